"""`umf serve` and `umf view`: the local web page that generates and plays scenes in 3-D."""

from __future__ import annotations

import os
import sys
import webbrowser
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import typer

from umf.errors import UMFError
from umf.validation import check_port

HOST_HELP = "Address to listen on; keep 127.0.0.1 unless you mean to share the page."


def _app(loader: Callable[[], Any] | None, pipeline: Any = None, verbose: bool = False,
         allowed_hosts: Sequence[str] = (), allowed_origins: Sequence[str] = ()):  # fmt: skip
    """The app, refusing to start without three.js (one line says what to install)."""
    from umf.serve.scenes import ModelHolder
    from umf.serve.server import App, find_three, three_missing_message

    three = find_three()
    if three is None:
        raise UMFError(three_missing_message())
    return App(
        ModelHolder(loader, pipeline),
        three,
        verbose=verbose,
        allowed_hosts=tuple(allowed_hosts),
        allowed_origins=tuple(allowed_origins),
    )


def _loader(model: Path | None) -> Callable[[], Any]:
    def load() -> Any:
        from umf.cli.loading import load_pipeline

        return load_pipeline(model)

    return load


def run_server(app: Any, host: str, port: int, open_browser: bool) -> None:
    """Serve until Ctrl+C; print the address first (tests read the port from it)."""
    from umf.serve.server import make_server

    try:
        server = make_server(app, host, port)
    except OSError as exc:
        raise UMFError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    bound_host, bound_port = server.server_address[:2]
    url = f"http://{'localhost' if bound_host == '127.0.0.1' else bound_host}:{bound_port}/"
    if host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(f"note: listening on {host}: anyone who can reach it can use the page")
    typer.echo(f"umf serve: {url}  (Ctrl+C stops)", err=False)
    sys.stdout.flush()
    if open_browser and _has_display():
        webbrowser.open(url)
    import signal

    def stop(signum: int, frame: Any) -> None:  # SIGTERM (systemd, docker, kill): as Ctrl+C
        raise KeyboardInterrupt

    import threading

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, stop) if main else None
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        typer.echo("umf serve: stopped")
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)
        server.server_close()
        app.close()


def _has_display() -> bool:
    """Only open a browser where one can show a window (never a text browser over SSH)."""
    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )


def serve(
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
    host: str = typer.Option("127.0.0.1", help=HOST_HELP),
    port: int = typer.Option(8000, help="Port (0: any free port; the address is printed)."),
    open_browser: bool = typer.Option(False, "--open/--no-open", help="Open a browser."),
    verbose: bool = typer.Option(False, "--verbose", help="Log every request to stderr."),
    allowed_host: list[str] = typer.Option([], "--allowed-host", help="A host name the page "
                                           "may be reached by besides loopback and --host "
                                           "(repeatable; for --host 0.0.0.0)."),
    allow_origin: list[str] = typer.Option([], "--allow-origin", help="Another web origin "
                                           "(scheme://host:port) allowed to POST (repeatable)."),
) -> None:  # fmt: skip
    """A local web page: type a prompt, see the scene in 3-D, download its files."""
    check_port(port)
    app = _app(
        _loader(model), verbose=verbose, allowed_hosts=allowed_host, allowed_origins=allow_origin
    )
    app.model.start()  # load while the user types
    run_server(app, host, port, open_browser)


def view(
    file: Path = typer.Argument(..., help="A scene: .npz or .glb (also a .bvh motion)."),
    model: Path | None = typer.Option(None, help="Model for new scenes (default: bundled)."),
    host: str = typer.Option("127.0.0.1", help=HOST_HELP),
    port: int = typer.Option(8000, help="Port (0: any free port; the address is printed)."),
    open_browser: bool = typer.Option(True, "--open/--no-open", help="Open a browser."),
) -> None:
    """Open the 3-D viewer of `umf serve` on an existing scene file."""
    from umf.serve.scenes import add_glb_file, add_motion_file

    check_port(port)
    if not file.is_file():
        raise UMFError(f"file not found: {file}")
    suffix = file.suffix.lower()
    if suffix not in (".npz", ".glb", ".bvh"):
        raise UMFError(f"{file}: cannot view this file (use .npz, .glb or .bvh)")
    app = _app(_loader(model))  # the model loads only if the page generates
    try:
        (add_glb_file if suffix == ".glb" else add_motion_file)(app.scenes, file)
    except BaseException:
        app.close()
        raise
    run_server(app, host, port, open_browser)


def view_scenes(scenes: Sequence[Any], pipeline: Any, params: dict[str, Any], port: int) -> None:
    """`umf generate --view`: the scenes just generated, in the page, model already loaded."""
    app = _app(None, pipeline)
    for scene in scenes:
        app.scenes.add_scene(scene, params)
    run_server(app, "127.0.0.1", port, True)
