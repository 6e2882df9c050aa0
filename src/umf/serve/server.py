"""`umf serve`: a local web page and JSON API that generate scenes and play them in 3-D.

Standard library only (``ThreadingHTTPServer``): the page is a few static files of this
package, three.js is served from the npm package ``make install`` put beside the venv, and
the model is loaded once in a background thread. Routes:

- ``GET /`` the page; ``GET /static/*`` its files; ``GET /vendor/three/*`` three.js;
- ``GET /api/health``; ``POST /api/generate`` (JSON, the CLI's fields); ``GET /api/scenes``
  and ``GET /api/scenes/ID``; ``POST /api/upload?name=F.bvh`` (react mode's actor);
  ``POST /api/reroll`` (``{"scene", "person", "seed"}``: one person of a scene again);
  ``POST``/``GET /api/scenes/ID/mp4`` (encode the MP4 in the background / its progress);
- ``GET /files/ID/NAME`` a scene's GLB, NPZ, BVH zip or MP4.

Every error is a JSON ``{"error": "one line"}`` with a 4xx status (5xx for the server's
own failures, whose traceback goes to the server's stderr, never to the client).
"""

from __future__ import annotations

import ipaddress
import json
import mimetypes
import os
import re
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np

from umf.errors import UMFError
from umf.serve.scenes import BUSY_WAIT_S, ActorStore, ModelHolder, SceneRecord, SceneStore
from umf.serve.validate import (
    GenerateRequest,
    RequestError,
    RerollRequest,
    parse_generate,
    parse_reroll,
)
from umf.version import __version__

THREE_VERSION = "0.187.0"
STATIC = Path(__file__).parent / "static"
MAX_JSON_BYTES = 64 * 1024
MAX_UPLOAD_BYTES = 20 * 1024 * 1024
READ_TIMEOUT_S = 30.0
REQUEST_DEADLINE_S = 60.0  # to receive a whole request (line, headers, body), however slowly
MAX_CONNECTIONS = 32  # open at once; more are answered 503 and closed
MOTION_SUFFIXES = (".bvh", ".npz")
_TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".glb": "model/gltf-binary",
          ".npz": "application/octet-stream", ".bvh": "text/plain", ".css": "text/css"}  # fmt: skip


# ------------------------------------------------------------------ three.js
def three_candidates() -> list[Path]:
    """Where the npm package ``three`` may be: $UMF_THREE_DIR alone when set, else the
    venv's node folder (what ``make install`` fills), then ./.venv/node and ./node_modules."""
    if os.environ.get("UMF_THREE_DIR"):
        return [Path(os.environ["UMF_THREE_DIR"])]
    return [
        Path(sys.prefix) / "node" / "node_modules" / "three",
        Path.cwd() / ".venv" / "node" / "node_modules" / "three",
        Path.cwd() / "node_modules" / "three",
    ]


def find_three() -> Path | None:
    return next((p for p in three_candidates() if (p / "build" / "three.module.js").is_file()),
                None)  # fmt: skip


def three_missing_message() -> str:
    node = Path(sys.prefix) / "node"
    return (
        f"three.js is missing: run `make install`, or `npm install --prefix {node} "
        f"three@{THREE_VERSION}` (or set UMF_THREE_DIR)"
    )


# ------------------------------------------------------------------ the application
class App:
    """State shared by all requests: model, scenes, uploads, where three.js is."""

    def __init__(self, model: ModelHolder, three: Path | None, workdir: Path | None = None,
                 verbose: bool = False, allowed_hosts: tuple[str, ...] = (),
                 allowed_origins: tuple[str, ...] = ()) -> None:  # fmt: skip
        self.allowed_hosts = tuple(h.lower() for h in allowed_hosts)
        self.allowed_origins = tuple(allowed_origins)
        self.model = model
        self.three = three
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="umf-serve-")
        self.workdir = workdir or Path(self._tmp.name)
        self.scenes = SceneStore(self.workdir / "scenes")
        self.actors = ActorStore()
        self.verbose = verbose

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()

    def health(self) -> dict[str, Any]:
        return {"status": "ok", "version": __version__, "model": self.model.info(),
                "busy": self.model.generating.locked(), "three": self.three is not None,
                "scenes": len(self.scenes.all())}  # fmt: skip

    def generate(self, req: GenerateRequest, session: str | None = None) -> dict[str, Any]:
        pipe = self.model.get()
        actor = self._actor_window(req, pipe, session) if req.actor else None
        if not self.model.generating.acquire(timeout=BUSY_WAIT_S):
            raise RequestError("the server is busy with another scene; try again", 503)
        begin = time.perf_counter()
        try:
            scene = pipe([req.prompt], num_people=req.people, seconds=req.seconds, seed=req.seed,
                         guidance=req.guidance, pflow_steps=req.steps,
                         sflow_steps=req.sflow_steps, actor=actor,
                         person_prompts=list(req.person_prompts) or None)[0]  # fmt: skip
        except UMFError as exc:
            raise RequestError(str(exc)) from None
        finally:
            self.model.generating.release()
        params = {"seed": req.seed, "guidance": req.guidance, "steps": req.steps,
                  "sflow_steps": req.sflow_steps, "actor": req.actor,
                  "generate_seconds": round(time.perf_counter() - begin, 3)}  # fmt: skip
        if req.person_prompts:
            params["person_prompts"] = scene.meta.get("person_prompts")
        record = self.scenes.add_scene(scene, params, session)
        return scene_json(record, req.joints)

    def reroll(self, req: RerollRequest, session: str | None = None) -> dict[str, Any]:
        """A new scene: person ``req.person`` of a stored scene generated again, everyone
        else as they were (``UMFPipeline.reroll``), from the scene's own NPZ."""
        from umf.data.motion_file import open_scene

        record = self.scenes.get(req.scene, session)
        if "npz" not in record.files:
            raise RequestError(f"scene {req.scene!r} holds no motion to re-roll")
        if not 1 <= req.person <= record.people:
            raise RequestError(f"scene {req.scene!r} has {record.people} people, "
                               f"no person {req.person}")  # fmt: skip
        pipe = self.model.get()
        try:
            scene = open_scene(record.folder / record.files["npz"])
        except UMFError as exc:
            raise RequestError(str(exc)) from None
        if not self.model.generating.acquire(timeout=BUSY_WAIT_S):
            raise RequestError("the server is busy with another scene; try again", 503)
        begin = time.perf_counter()
        try:
            new = pipe.reroll(scene, req.person, seed=req.seed, person_prompt=req.person_prompt)
        except UMFError as exc:
            raise RequestError(str(exc)) from None
        finally:
            self.model.generating.release()
        params = {**record.params, "rerolled_from": record.id,
                  "reroll": {"person": req.person, "seed": req.seed},
                  "generate_seconds": round(time.perf_counter() - begin, 3)}  # fmt: skip
        params.pop("coverage", None)
        params.pop("person_coverage", None)
        if new.meta.get("person_prompts"):
            params["person_prompts"] = new.meta["person_prompts"]
        return scene_json(self.scenes.add_scene(new, params, session), req.joints)

    def _actor_window(self, req: GenerateRequest, pipe: Any, session: str | None) -> np.ndarray:
        """Person ``actor_person`` of the upload, from ``start`` for ``seconds`` (capped at
        the model's longest motion): what `umf react` does with --start/--seconds."""
        from umf.data.motion_file import FPS

        motion = self.actors.get(req.actor, session)
        if req.actor_person > motion.num_people:
            raise RequestError(f"the uploaded motion has {motion.num_people} people, "
                               f"no person {req.actor_person}")  # fmt: skip
        first = round(req.start * FPS)
        if first >= motion.frames:
            raise RequestError(f"'start' {req.start:g} s is outside the uploaded motion "
                               f"({motion.frames / FPS:.1f} s)")  # fmt: skip
        count = min(round(req.seconds * FPS) + 1, pipe.config.vae.max_frames + 1)
        try:  # only the window is resampled and fitted (a long upload costs its window)
            return motion.scene(first, count).joints[req.actor_person - 1]
        except UMFError as exc:
            raise RequestError(str(exc)) from None

    def upload(self, name: str, data: bytes, session: str | None = None) -> dict[str, Any]:
        """An actor motion (.bvh/.npz) read and checked by ``open_motion`` and kept as read
        (resampled and fitted only for the window a react asks for); returns its id."""
        from umf.data.motion_file import FPS, open_motion

        suffix = Path(name).suffix.lower()
        if suffix not in MOTION_SUFFIXES:
            raise RequestError("upload a .bvh or .npz motion file (?name=FILE.bvh)", 415)
        folder = self.workdir / "uploads"
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=suffix, dir=folder)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            motion = open_motion(tmp)
        except UMFError as exc:
            raise RequestError(str(exc).replace(tmp, Path(name).name)) from None
        except Exception as exc:  # a parser failing on garbage is still the file's fault
            raise RequestError(f"{Path(name).name}: not a readable motion file "
                               f"({type(exc).__name__})") from None  # fmt: skip
        finally:
            Path(tmp).unlink(missing_ok=True)
        aid = self.actors.add(motion, session)
        return {"actor": aid, "name": Path(name).name, "people": motion.num_people,
                "frames": motion.frames, "seconds": round(motion.frames / FPS, 3),
                "text": motion.text}  # fmt: skip


def scene_json(record: SceneRecord, with_joints: bool = True) -> dict[str, Any]:
    """The API's view of a scene: parameters, file links and the joints (mm precision)."""
    out = record.summary()
    if with_joints and record.joints is not None:
        out["joints"] = np.round(record.joints.astype(np.float64), 3).tolist()
    return out


# ------------------------------------------------------------------ HTTP
class Handler(BaseHTTPRequestHandler):
    """Routes of the module docstring; every response is complete and bounded."""

    server_version = f"umf/{__version__}"
    timeout = READ_TIMEOUT_S  # a client that stops sending is dropped
    app: App  # set on the subclass made by make_server

    def handle_one_request(self) -> None:
        """One request, received within REQUEST_DEADLINE_S in all: the 30 s timeout is per
        read, so a client sending a byte every 10 s would otherwise hold a thread forever."""
        self._deadline = threading.Timer(REQUEST_DEADLINE_S, self._cut_off)
        self._deadline.daemon = True
        self._deadline.start()
        try:
            super().handle_one_request()
        finally:
            self._deadline.cancel()

    def _received(self) -> None:
        """The whole request is in: the deadline no longer applies (generation may be slow)."""
        deadline = getattr(self, "_deadline", None)
        if deadline is not None:
            deadline.cancel()

    def _cut_off(self) -> None:
        import socket

        self.close_connection = True
        try:
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def log_message(self, format: str, *args: Any) -> None:
        if self.app.verbose:
            sys.stderr.write(f"umf serve: {self.address_string()} {format % args}\n")

    # -- dispatch
    def do_GET(self) -> None:
        self._dispatch("GET")

    def do_POST(self) -> None:
        self._dispatch("POST")

    def do_PUT(self) -> None:
        self._dispatch("PUT")

    def do_DELETE(self) -> None:
        self._dispatch("DELETE")

    def do_PATCH(self) -> None:
        self._dispatch("PATCH")

    def do_OPTIONS(self) -> None:  # no CORS preflight is ever granted: one JSON line
        self._dispatch("OPTIONS")

    def do_HEAD(self) -> None:
        self.close_connection = True  # the JSON error's body follows a HEAD: end there
        self._dispatch("HEAD")

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """http.server's own errors (414 URI too long, 431 headers too large, 400 bad request
        line, 501) as one JSON line, like every other error."""
        self.close_connection = True
        try:
            self._json({"error": message or self.responses.get(code, ("error",))[0]}, code)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            pass

    def _dispatch(self, method: str) -> None:
        try:
            self._answer(method)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            self.close_connection = True  # the client left before its answer: nothing to say

    def _answer(self, method: str) -> None:
        self.session, self._new_session = read_session(self.headers.get("Cookie"))
        try:
            self._check_host()
            if method not in ("GET", "HEAD"):
                self._check_origin()
            else:
                self._received()
            path = urlsplit(self.path).path
            route = self._route(method, path)
            if route is None:
                raise RequestError(f"no such page: {method} {path}", 404)
            route()
        except RequestError as exc:
            self._json({"error": str(exc)}, exc.status)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            self.close_connection = True
        except Exception as exc:  # the server's own failure: log it, tell the client one line
            traceback.print_exc(file=sys.stderr)
            self._json({"error": f"internal error ({type(exc).__name__}); see the server log"},
                       500)  # fmt: skip

    def _route(self, method: str, path: str) -> Callable[[], None] | None:
        parts = [unquote(p) for p in path.strip("/").split("/")] if path != "/" else []
        gets: dict[tuple[str, ...], Callable[[], None]] = {
            (): lambda: self._file(STATIC / "index.html"),
            ("api", "health"): lambda: self._json(self.app.health()),
            ("api", "scenes"): lambda: self._json(
                {"scenes": [r.summary() for r in self.app.scenes.all(self.session)]}),
        }  # fmt: skip
        posts: dict[tuple[str, ...], Callable[[], None]] = {
            ("api", "generate"): self._post_generate,
            ("api", "upload"): self._post_upload,
            ("api", "reroll"): self._post_reroll,
        }
        table = gets if method == "GET" else posts if method == "POST" else {}
        if tuple(parts) in table:
            return table[tuple(parts)]
        if method == "GET" and len(parts) == 2 and parts[0] == "static":
            return lambda: self._static(parts[1])
        if method == "GET" and len(parts) >= 3 and parts[:2] == ["vendor", "three"]:
            return lambda: self._three(parts[2:])
        if method == "GET" and len(parts) == 3 and parts[0] == "files":
            return lambda: self._scene_file(parts[1], parts[2])
        if len(parts) == 3 and parts[:2] == ["api", "scenes"] and method == "GET":
            return lambda: self._json(scene_json(self.app.scenes.get(parts[2], self.session)))
        if len(parts) == 4 and parts[:2] == ["api", "scenes"] and parts[3] == "mp4":
            if method in ("GET", "POST"):
                return lambda: self._video(parts[2], start=method == "POST")
        mp4 = len(parts) == 4 and parts[:2] == ["api", "scenes"] and parts[3] == "mp4"
        if mp4 or any(tuple(parts) in t for t in (gets, posts)):
            return lambda: self._wrong_method(method)
        return None

    def _wrong_method(self, method: str) -> None:
        raise RequestError(f"{method} is not allowed here", 405)

    def _check_host(self) -> None:
        """Only Host names the server answers to are served, so a web page elsewhere cannot
        reach it through DNS rebinding: loopback names, and on another address that address
        and the names of ``--allowed-host``. The header is parsed as an authority (a name or
        IP and an optional port, nothing else: ``localhost:80@evil.com`` is refused)."""
        name = parse_host(self.headers.get("Host") or "")
        if name is None:
            raise RequestError(f"bad Host header {self.headers.get('Host', '')!r:.80}", 400)
        bound = self.server.server_address[0]
        if name in ("localhost", "") or _is_loopback(name):
            return
        if not _is_loopback(bound) and (name == bound.lower() or name in self.app.allowed_hosts):
            return
        if bound in ("0.0.0.0", "::") and _is_ip(name):  # reached by one of its addresses
            return
        raise RequestError(f"host {name!r} not allowed (umf serve --allowed-host NAME)", 403)

    def _check_origin(self) -> None:
        """A state-changing request from a browser must come from the page itself (its
        Origin is this server's) or from ``--allow-origin``; any other web page is refused,
        whatever it sends (no-cors fetch, sendBeacon, a form). Clients that send no Origin
        (curl, scripts) are not browsers and pass."""
        origin = self.headers.get("Origin")
        if origin is None:
            return
        own = f"http://{(self.headers.get('Host') or '').strip().lower()}"
        if origin.strip().lower() != own and origin.strip() not in self.app.allowed_origins:
            raise RequestError(f"requests from {origin!r:.80} are not allowed", 403)

    # -- bodies
    def _body(self, limit: int) -> bytes:
        length = self.headers.get("Content-Length")
        if length is None:
            raise RequestError("a Content-Length header is required", 411)
        try:
            size = int(length)
        except ValueError:
            raise RequestError("bad Content-Length header") from None
        if size < 0:
            raise RequestError("bad Content-Length header")
        if size > limit:
            self.close_connection = True  # the rest of the body is not read
            raise RequestError(f"the request body is larger than {limit} bytes", 413)
        data = self.rfile.read(size)
        self._received()
        if len(data) != size:
            raise RequestError("the request body ended early")
        return data

    def _json_body(self) -> Any:
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":  # never text/plain: a cross-site form could send it
            raise RequestError("send the fields as JSON (Content-Type: application/json)", 415)
        data = self._body(MAX_JSON_BYTES)
        try:
            return json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise RequestError("the request body is not valid JSON") from None
        except RecursionError:  # [[[[...]]]] 30,000 deep fits in 64 KB
            raise RequestError("the request body nests too deeply") from None

    def _post_generate(self) -> None:
        request = parse_generate(self._json_body())
        self._json(self.app.generate(request, self.session))

    def _post_reroll(self) -> None:
        self._json(self.app.reroll(parse_reroll(self._json_body()), self.session))

    def _post_upload(self) -> None:
        query = parse_qs(urlsplit(self.path).query)
        name = (query.get("name") or [""])[0]
        if not name:
            raise RequestError("name the file: POST /api/upload?name=FILE.bvh")
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/octet-stream":  # the types a cross-site form can send are not
            raise RequestError("send the file as Content-Type: application/octet-stream", 415)
        self._json(self.app.upload(name, self._body(MAX_UPLOAD_BYTES), self.session))

    def _video(self, sid: str, start: bool) -> None:
        record = self.app.scenes.get(sid, self.session)
        video = self.app.scenes.start_video(record) if start else record.video
        out = {"state": video.state, "done": video.done, "total": video.total,
               "error": video.error}  # fmt: skip
        if video.state == "done":
            out["url"] = f"/files/{sid}/{record.files['mp4']}"
        self._json(out, 202 if start and video.state == "running" else 200)

    # -- files
    def _static(self, name: str) -> None:
        path = STATIC / name
        if "/" in name or name.startswith(".") or not path.is_file():
            raise RequestError(f"no such file: {name}", 404)
        self._file(path)

    def _three(self, parts: list[str]) -> None:
        three = self.app.three
        if three is None:
            raise RequestError(three_missing_message(), 404)
        path = (three / "/".join(parts)).resolve()
        allowed = [(three / "build").resolve(), (three / "examples" / "jsm").resolve()]
        inside = any(path.is_relative_to(a) for a in allowed)
        if not inside or path.suffix != ".js" or not path.is_file():
            raise RequestError(f"no such three.js file: {'/'.join(parts)}", 404)
        self._file(path, cache=True)

    def _scene_file(self, sid: str, name: str) -> None:
        record = self.app.scenes.get(sid, self.session)
        if name not in record.files.values():
            raise RequestError(f"scene {sid} has no file {name!r}", 404)
        self._file(record.folder / name, download=name)

    def _file(self, path: Path, cache: bool = False, download: str | None = None) -> None:
        data = path.read_bytes()
        kind = _TYPES.get(path.suffix.lower()) or mimetypes.guess_type(path.name)[0]
        self.send_response(200)
        self.send_header("Content-Type", kind or "application/octet-stream")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "max-age=3600" if cache else "no-cache")
        if download:
            self.send_header("Content-Disposition", content_disposition(download))
        self._session_cookie()
        self.end_headers()
        self.wfile.write(data)

    def _json(self, obj: Any, status: int = 200) -> None:
        data = json.dumps(obj, separators=(",", ":")).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-cache")
        self._session_cookie()
        self.end_headers()
        self.wfile.write(data)

    def _session_cookie(self) -> None:
        if getattr(self, "_new_session", False):
            self.send_header("Set-Cookie", f"{SESSION_COOKIE}={self.session}; Path=/; HttpOnly; "
                             "SameSite=Strict")  # fmt: skip


SESSION_COOKIE = "umf_session"
_SESSION_RE = re.compile(r"[A-Za-z0-9_-]{32}")


def read_session(cookie: str | None) -> tuple[str, bool]:
    """(session id, whether it is new) from a Cookie header: each browser gets an
    unguessable id, and sees only its own scenes and uploads."""
    import secrets
    from http.cookies import CookieError, SimpleCookie

    jar = SimpleCookie()
    try:
        jar.load(cookie or "")
    except CookieError:
        pass
    morsel = jar.get(SESSION_COOKIE)
    if morsel is not None and _SESSION_RE.fullmatch(morsel.value):
        return morsel.value, False
    return secrets.token_urlsafe(24), True


def content_disposition(name: str) -> str:
    """``attachment`` with an ASCII fallback name (quotes, backslashes and control
    characters replaced) and the exact name as RFC 6266/5987 ``filename*``: no header
    injection, any Unicode name."""
    from urllib.parse import quote

    plain = "".join(c if 32 <= ord(c) < 127 and c not in '"\\' else "_" for c in name)
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(name, safe='')}"


_HOST = re.compile(r"^(?:\[([0-9a-fA-F:.]+)\]|([A-Za-z0-9.-]*))(?::(\d{1,5}))?$")


def parse_host(value: str) -> str | None:
    """The host name of a Host header (lower case, IPv6 without brackets), or None when
    the header is not a bare ``host[:port]`` authority."""
    m = _HOST.match(value.strip())
    if m is None:
        return None
    return (m.group(1) or m.group(2) or "").lower()


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


class CappedServer(ThreadingHTTPServer):
    """One thread per connection, at most ``MAX_CONNECTIONS`` at once: the next is answered
    503 in one JSON line and closed, so a crowd of idle clients cannot exhaust threads."""

    daemon_threads = True
    max_connections = MAX_CONNECTIONS

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._open = threading.BoundedSemaphore(self.max_connections)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._open.acquire(blocking=False):
            body = b'{"error":"too many connections; try again"}'
            try:
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: "
                                b"application/json\r\nConnection: close\r\nContent-Length: "
                                + str(len(body)).encode() + b"\r\n\r\n" + body)  # fmt: skip
            except OSError:
                pass
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._open.release()


def make_server(app: App, host: str = "127.0.0.1", port: int = 8000) -> ThreadingHTTPServer:
    """A server bound to ``host:port`` (port 0: a free one) serving ``app``."""
    handler = type("UMFHandler", (Handler,), {"app": app})
    return CappedServer((host, port), handler)


def start_in_thread(app: App, host: str = "127.0.0.1", port: int = 0) -> ThreadingHTTPServer:
    """Serve in a daemon thread (tests, ``umf generate --view``); ``shutdown()`` stops it."""
    server = make_server(app, host, port)
    threading.Thread(target=server.serve_forever, name="umf-serve", daemon=True).start()
    return server
