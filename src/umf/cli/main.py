"""Entry point of the `umf` command: subcommand groups and one-line error handling."""

from __future__ import annotations

import signal
import sys
import threading
from typing import Any

import typer

from umf.cli.data import app as data_app
from umf.cli.eval import evaluate
from umf.cli.generate import generate, react, reroll
from umf.cli.info import info
from umf.cli.serve import serve, view
from umf.cli.train import app as train_app
from umf.errors import UMFError
from umf.version import __version__

try:  # typer >= 0.20 parses with its own copy of click
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover - older typer uses click itself
    from click import exceptions as click_errors

app = typer.Typer(
    name="umf",
    help="Unified Motion Flow: text + number of people -> synchronized 3-D motion.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(data_app, name="data")
app.add_typer(train_app, name="train")
app.command("generate")(generate)
app.command("react")(react)
app.command("reroll")(reroll)
app.command("eval")(evaluate)
app.command("serve")(serve)
app.command("view")(view)
app.command("info")(info)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"umf {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Unified Motion Flow: text + number of people -> synchronized 3-D motion."""


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def disk_full(exc: BaseException) -> str | None:
    """One line for a full disk (or quota) anywhere in an exception's chain, naming the file
    when the error does; None for any other error. Outputs are written atomically, so what
    was there before is intact."""
    import errno

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            where = f" writing {exc.filename}" if exc.filename else ""
            return f"no space left on device{where} (nothing half-written was kept)"
        exc = exc.__cause__ or exc.__context__
    return None


class Terminated(KeyboardInterrupt):
    """SIGTERM (kill, systemd, docker stop), raised where Ctrl+C would be, so that the same
    clean-up runs: no temporary folder or half-written file is left behind."""


def run(argv: list[str] | None = None) -> None:
    """Console-script entry: user errors become one line on stderr and a non-zero exit
    (1 for bad values and files, 2 for malformed command lines, as click uses; 130 after
    Ctrl+C, 143 after SIGTERM)."""
    got: list[int] = []

    def terminate(signum: int, frame: Any) -> None:
        got.append(signum)
        raise Terminated

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, terminate) if main else None
    try:
        _run(argv, got)
    except BaseException as exc:
        # raised inside a C extension, the signal's exception can come out as another
        # (a TypeError from matplotlib): after SIGTERM, whatever ends the run says so
        if got and not (isinstance(exc, SystemExit) and exc.code in (0, None)):
            print("umf: terminated", file=sys.stderr)
            sys.exit(143)
        raise
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)


def _run(argv: list[str] | None, got: list[int]) -> None:
    """The command's outcome as a one-line message and an exit code; ``got``: the signals
    run() caught (SIGTERM: "terminated", left to run())."""
    try:
        try:
            code = app(args=argv, standalone_mode=False)
        except BaseException:
            if got:  # whatever the signal's exception became on its way up
                raise Terminated from None
            raise
    except click_errors.NoArgsIsHelpError as exc:
        exc.show()  # `umf` or `umf train` alone: the help, as before
        sys.exit(exc.exit_code)
    except click_errors.UsageError as exc:
        print(f"umf: error: {_one_line(exc.format_message())}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except Terminated:
        raise
    except (typer.Abort, KeyboardInterrupt):  # Abort: click's word for Ctrl+C
        print("umf: interrupted", file=sys.stderr)
        sys.exit(130)
    except UMFError as exc:
        print(f"umf: error: {_one_line(str(exc))}", file=sys.stderr)
        sys.exit(1)
    except Exception as exc:  # a full disk under any wrapper; anything else is a bug: raise
        full = disk_full(exc)
        if full is None:
            raise
        print(f"umf: error: {full}", file=sys.stderr)
        sys.exit(1)
    if code == 130:  # typer turns Ctrl-C (and a SIGTERM) into exit code 130
        if got:
            raise Terminated
        print("umf: interrupted", file=sys.stderr)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    run()
