"""`umf serve` against a hostile web page: cross-origin and content-type rules, Host
parsing, JSON for every error, safe download names. No model is loaded (no request here
gets that far)."""

from __future__ import annotations

import http.client
import json

import pytest

from umf.serve.scenes import ModelHolder
from umf.serve.server import App, content_disposition, parse_host, start_in_thread


def _never():
    raise AssertionError("no request of these tests may load the model")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    app = App(ModelHolder(_never), None, workdir=tmp_path_factory.mktemp("srv"),
              allowed_origins=("http://tools.example:9000",))  # fmt: skip
    srv = start_in_thread(app)
    yield srv.server_address[1]
    srv.shutdown()
    srv.server_close()


def ask(port, method, path, body=b"", headers=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    hdrs = {"Host": f"localhost:{port}", **(headers or {})}
    conn.request(method, path, body=body or None, headers=hdrs)
    r = conn.getresponse()
    data = r.read()
    conn.close()
    return r.status, dict(r.getheaders()), data


def error(answer) -> tuple[int, str]:
    status, headers, data = answer
    assert headers["Content-Type"] == "application/json", data[:200]
    return status, json.loads(data)["error"]


BODY = json.dumps({"prompt": "a", "people": 1}).encode()


@pytest.mark.parametrize(
    ("headers", "status", "needle"),
    [({"Content-Type": "application/json", "Origin": "https://evil.example"}, 403, "not allowed"),
     ({"Content-Type": "text/plain"}, 415, "JSON"),  # what a no-cors fetch or a form sends
     ({}, 415, "JSON"),  # a Blob body with no type
     ({"Content-Type": "application/x-www-form-urlencoded"}, 415, "JSON")],
)  # fmt: skip
def test_a_cross_site_page_cannot_generate(server, headers, status, needle):
    got = error(ask(server, "POST", "/api/generate", BODY, headers))
    assert got[0] == status and needle in got[1]


def test_the_page_itself_and_an_allowed_origin_get_through_the_origin_check(server):
    for origin in (f"http://localhost:{server}", "http://tools.example:9000"):
        status, msg = error(ask(server, "POST", "/api/generate", b"{}", {
            "Content-Type": "application/json", "Origin": origin}))  # fmt: skip
        assert status == 400 and "not allowed" not in msg  # refused for its fields, not origin


@pytest.mark.parametrize("kind", ["text/plain", "multipart/form-data", None])
def test_uploads_only_as_octet_stream(server, kind):
    headers = {} if kind is None else {"Content-Type": kind}
    status, msg = error(ask(server, "POST", "/api/upload?name=a.bvh", b"HIERARCHY", headers))
    assert status == 415 and "octet-stream" in msg


@pytest.mark.parametrize(
    ("host", "status"),
    [("evil.example", 403), ("localhost:1@evil.example", 400), ("localhost.evil.example", 403),
     ("127.0.0.1.nip.io", 403), ("a b", 400)],
)  # fmt: skip
def test_host_names_other_than_loopback_are_refused(server, host, status):
    assert error(ask(server, "GET", "/api/health", headers={"Host": host}))[0] == status
    assert ask(server, "GET", "/api/health", headers={"Host": "[::1]:80"})[0] == 200


@pytest.mark.parametrize("method", ["OPTIONS", "PATCH", "PUT", "DELETE"])
def test_other_methods_answer_one_json_line(server, method):
    status, _ = error(
        ask(server, method, "/api/generate", b"", {"Origin": f"http://localhost:{server}"})
    )
    assert status in (404, 405)


def test_head_and_http_servers_own_errors_are_json(server):
    status, headers, _ = ask(server, "HEAD", "/api/health")
    assert status in (404, 405) and headers["Content-Type"] == "application/json"
    status, _ = error(ask(server, "GET", "/" + "a" * 70_000))  # http.server: 414
    assert status == 414


def test_download_names_cannot_inject_headers():
    value = content_disposition('x"\r\nSet-Cookie: a=b.glb')
    assert "\r" not in value and "\n" not in value
    assert value.startswith("attachment; filename=\"x___Set-Cookie: a=b.glb\"; filename*=UTF-8''")
    assert "%0D%0A" in value
    assert parse_host("localhost:8000@evil.com") is None and parse_host("[::1]:8000") == "::1"


def _glb(path, doc) -> None:
    import struct

    data = json.dumps(doc).encode()
    data += b" " * (-len(data) % 4)
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 20 + len(data))
                     + struct.pack("<I4s", len(data), b"JSON") + data)  # fmt: skip


@pytest.mark.parametrize(
    ("doc", "needle"),
    [({"asset": {"extras": {"fps": "abc"}}}, "not a number"),
     ({"asset": {"extras": {"fps": "0"}}}, "not a frame rate"),
     ({"asset": {"extras": {"fps": "nan"}}}, "not a frame rate"),
     ([1, 2], "not an object")],
)  # fmt: skip
def test_a_glb_with_wrong_extras_is_one_line_and_never_stored(tmp_path, doc, needle):
    from umf.errors import UMFError
    from umf.serve.scenes import SceneStore, add_glb_file

    store = SceneStore(tmp_path / "scenes")
    _glb(tmp_path / "x.glb", doc)
    with pytest.raises(UMFError, match=needle):
        add_glb_file(store, tmp_path / "x.glb")
    assert store.all() == []
    _glb(tmp_path / "y.glb", {"asset": {"extras": {"people": 3, "seed": "x", "text": 5}}})
    record = add_glb_file(store, tmp_path / "y.glb")  # odd but harmless extras: ignored
    assert record.people == 0 and record.params["seed"] is None and record.text == "y"


def test_json_nested_too_deep_is_a_400(server):
    body = b"[" * 30_000 + b"]" * 30_000
    status, msg = error(ask(server, "POST", "/api/generate", body,
                            {"Content-Type": "application/json"}))  # fmt: skip
    assert status == 400 and "nests too deeply" in msg


def test_each_browser_sees_only_its_own_scenes_and_uploads(tmp_path):
    """Two sessions: a scene and an upload of one are invisible (404) to the other; scenes
    opened by `umf view` (no session) are everybody's."""
    import numpy as np

    from umf.scene import Scene
    from umf.serve.server import SESSION_COOKIE

    app = App(ModelHolder(_never), None, workdir=tmp_path)
    joints = np.zeros((1, 20, 22, 3), np.float32)
    joints[..., 1] = np.linspace(0, 1.7, 22)[None, None, :]
    mine = app.scenes.add_scene(Scene(joints, None, "mine", 30.0), {}, session="A" * 32)
    shared = app.scenes.add_scene(Scene(joints, None, "shared", 30.0), {})
    aid = app.actors.add(object(), session="A" * 32)
    srv = start_in_thread(app)
    port = srv.server_address[1]
    try:
        a = {"Cookie": f"{SESSION_COOKIE}={'A' * 32}"}
        b = {"Cookie": f"{SESSION_COOKIE}={'B' * 32}"}

        def listed(h):
            answer = json.loads(ask(port, "GET", "/api/scenes", headers=h)[2])
            return [s["id"] for s in answer["scenes"]]

        assert listed(a) == [mine.id, shared.id] and listed(b) == [shared.id]
        assert ask(port, "GET", f"/api/scenes/{mine.id}", headers=b)[0] == 404
        assert ask(port, "GET", f"/files/{mine.id}/{mine.files['glb']}", headers=b)[0] == 404
        assert ask(port, "GET", f"/files/{mine.id}/{mine.files['glb']}", headers=a)[0] == 200
        _, headers, _ = ask(port, "GET", "/api/health")  # no cookie: a new session
        assert (
            SESSION_COOKIE in headers.get("Set-Cookie", "") and "HttpOnly" in headers["Set-Cookie"]
        )
        assert "Set-Cookie" not in ask(port, "GET", "/api/health", headers=a)[1]
    finally:
        srv.shutdown()
        srv.server_close()
    from umf.serve.validate import RequestError

    with pytest.raises(RequestError):
        app.actors.get(aid, "B" * 32)
    assert app.actors.get(aid, "A" * 32) is not None


def test_a_slow_client_is_cut_off_and_too_many_connections_are_refused(tmp_path, monkeypatch):
    import socket
    import time

    import umf.serve.server as srv_mod

    monkeypatch.setattr(srv_mod, "REQUEST_DEADLINE_S", 1.0)
    monkeypatch.setattr(srv_mod.CappedServer, "max_connections", 3)
    app = App(ModelHolder(_never), None, workdir=tmp_path)
    srv = start_in_thread(app)
    port = srv.server_address[1]
    try:
        slow = socket.create_connection(("127.0.0.1", port), timeout=10)
        slow.sendall(b"GET /api/health HTTP/1.1\r\n")  # then a header, very slowly
        begin = time.perf_counter()
        closed = False
        while time.perf_counter() - begin < 6:
            try:
                slow.sendall(b"X")
                time.sleep(0.3)
            except OSError:
                closed = True
                break
            slow.settimeout(0.01)
            try:
                if slow.recv(1) == b"":
                    closed = True
                    break
            except (TimeoutError, BlockingIOError):
                pass
            except OSError:
                closed = True
                break
        assert closed and time.perf_counter() - begin < 4  # cut at the 1 s deadline
        idle = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(3)]
        time.sleep(0.2)
        extra = socket.create_connection(("127.0.0.1", port), timeout=10)
        answer = extra.recv(4096)
        assert answer.startswith(b"HTTP/1.1 503") and b"too many connections" in answer
        for s in idle:
            s.close()
        time.sleep(1.5)  # the idle ones are released (closed, or cut at the deadline)
        assert ask(port, "GET", "/api/health")[0] == 200
    finally:
        srv.shutdown()
        srv.server_close()


def test_a_client_that_leaves_before_its_error_leaves_no_traceback(tmp_path, capfd, monkeypatch):
    """Writing the one-line error to a client that has gone (a reset, a slow client cut at
    the deadline) fails with a broken pipe: the server says nothing more and logs no
    traceback for it, and keeps answering."""
    import umf.serve.server as srv_mod

    app = App(ModelHolder(_never), None, workdir=tmp_path)
    srv = start_in_thread(app)
    port = srv.server_address[1]
    real_json = srv_mod.Handler._json
    gone = {"n": 0}

    def broken(self, *args, **kwargs):
        if gone["n"] == 0:
            gone["n"] += 1
            raise BrokenPipeError(32, "Broken pipe")
        return real_json(self, *args, **kwargs)

    monkeypatch.setattr(srv_mod.Handler, "_json", broken)
    try:
        with pytest.raises(http.client.RemoteDisconnected):
            ask(port, "GET", "/no/such/page")  # a 404 that cannot be written
        assert ask(port, "GET", "/api/health")[0] == 200
    finally:
        srv.shutdown()
        srv.server_close()
    assert gone["n"] == 1 and "Traceback" not in capfd.readouterr().err
