"""`umf serve`'s JSON API through a real in-process server on a free loopback port: valid
requests, every class of bad input (4xx + a one-line JSON message, never a traceback),
limits, file downloads, react uploads, MP4 progress and `umf view`'s scene files."""

from __future__ import annotations

import io
import json
import sys
import time
import urllib.error
import urllib.request
import zipfile

import numpy as np
import pytest

from conftest import BANDAI_FIXTURE
from umf.errors import UMFError
from umf.serve.scenes import ModelHolder, add_glb_file, add_motion_file
from umf.serve.server import MAX_JSON_BYTES, App, find_three, start_in_thread

BOW = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"


# one browser: its session cookie comes back with every request, as the page's does
BROWSER = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())


def request(base: str, path: str, body=None, method=None, headers=None, raw: bytes | None = None):
    """(status, headers, bytes) of one request; errors are answers too."""
    data = raw if raw is not None else None if body is None else json.dumps(body).encode()
    hdrs = {"Content-Type": "application/json"} if body is not None else {}
    if raw is not None and path.startswith("/api/upload"):  # what the page sends
        hdrs = {"Content-Type": "application/octet-stream"}
    req = urllib.request.Request(
        base + path, data=data, method=method, headers=hdrs | (headers or {})
    )
    try:
        with BROWSER.open(req, timeout=600) as r:  # a starved CPU loads slowly
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()


def as_json(answer):
    status, headers, data = answer
    assert headers["Content-Type"] == "application/json"
    return status, json.loads(data)


@pytest.fixture(scope="module")
def server(tmp_path_factory, one_thread):
    """The bundled model behind a server on a free port; yields its base URL and app."""
    from umf.pipeline import UMFPipeline

    app = App(
        ModelHolder(UMFPipeline.from_pretrained),
        find_three(),
        workdir=tmp_path_factory.mktemp("serve"),
    )
    app.model.start()
    httpd = start_in_thread(app)
    yield f"http://127.0.0.1:{httpd.server_address[1]}", app
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture(scope="module")
def scene(server):
    base, _ = server
    status, body = as_json(
        request(
            base,
            "/api/generate",
            {"prompt": "Three people walk side by side.", "people": 3, "seconds": 2, "seed": 7},
        )
    )
    assert status == 200, body
    return body


def test_health_and_page(server):
    base, _ = server
    status, health = as_json(request(base, "/api/health"))
    assert (
        status == 200
        and health["status"] == "ok"
        and health["model"]["state"] in ("loading", "ready")
    )
    status, headers, page = request(base, "/")
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert b'src="/static/app.js"' in page and b"/vendor/three/build/three.module.js" in page
    for path in ("/static/app.js", "/static/viewer.js", "/static/style.css"):
        assert request(base, path)[0] == 200, path


def test_three_is_served_from_npm_and_nothing_else(server):
    base, app = server
    if app.three is None:
        pytest.skip("three.js not installed (make install puts it under .venv/node)")
    status, headers, js = request(base, "/vendor/three/build/three.module.js")
    assert status == 200 and headers["Content-Type"] == "text/javascript"
    assert b"three.core.js" in js or b"REVISION" in js
    assert request(base, "/vendor/three/examples/jsm/loaders/GLTFLoader.js")[0] == 200
    for path in (
        "/vendor/three/package.json",
        "/vendor/three/../../../etc/passwd",
        "/vendor/three/build/%2e%2e/package.json",
        "/static/../server.py",
        "/static/%2e%2e%2fserver.py",
        "/files/s1/..%2f..%2fetc",
    ):
        assert request(base, path)[0] == 404, path


def test_generate_returns_the_scene_and_its_files(server, scene):
    base, _ = server
    joints = np.array(scene["joints"])
    assert joints.shape == (3, 60, 22, 3) and np.isfinite(joints).all()
    assert scene["people"] == 3 and scene["frames"] == 60 and scene["seed"] == 7
    assert scene["coverage"]["known"] and scene["coverage"]["nearest"]  # the model knows it
    status, headers, glb = request(base, scene["files"]["glb"])
    assert status == 200 and glb[:4] == b"glTF" and len(glb) == int.from_bytes(glb[8:12], "little")
    assert headers["Content-Disposition"].startswith("attachment")
    status, _, npz = request(base, scene["files"]["npz"])
    with np.load(io.BytesIO(npz)) as z:
        np.testing.assert_allclose(z["joints"], joints, atol=1e-3)
    status, _, data = request(base, scene["files"]["bvh"])
    names = zipfile.ZipFile(io.BytesIO(data)).namelist()
    assert len(names) == 3 and all(n.endswith(f"-p{i}.bvh") for i, n in enumerate(names, 1))
    status, listed = as_json(request(base, "/api/scenes"))
    assert scene["id"] in [s["id"] for s in listed["scenes"]]
    status, again = as_json(request(base, f"/api/scenes/{scene['id']}"))
    assert again["joints"] == scene["joints"]


def test_same_seed_same_scene_and_cli_style_steps(server, scene):
    base, _ = server
    body = {"prompt": "Three people walk side by side.", "people": 3, "seconds": 2, "seed": 7}
    status, same = as_json(request(base, "/api/generate", body))
    assert status == 200 and same["joints"] == scene["joints"]
    for steps in ("4,2", [4, 2]):
        status, out = as_json(
            request(
                base,
                "/api/generate",
                {
                    "prompt": "A person waves.",
                    "people": 1,
                    "seconds": 1,
                    "steps": steps,
                    "sflow_steps": 2,
                    "guidance": 1.5,
                    "joints": False,
                },
            )
        )
        assert status == 200 and "joints" not in out and out["steps"] == [4, 2]


BAD = [
    ({"people": 3}, "prompt"),
    ({"prompt": "   "}, "empty"),
    ({"prompt": "x" * 501}, "longer than 500"),
    ({"prompt": 5}, "prompt"),
    ({"prompt": "a", "colour": "red"}, "unknown field"),
    ({"prompt": "a", "people": 0}, "between 1 and 16"),
    ({"prompt": "a", "people": 17}, "between 1 and 16"),
    ({"prompt": "a", "people": "3"}, "integer"),
    ({"prompt": "a", "people": 2.5}, "integer"),
    ({"prompt": "a", "people": True}, "integer"),
    ({"prompt": "a", "seconds": 0.1}, "between 0.5 and 10"),
    ({"prompt": "a", "seconds": 11}, "between 0.5 and 10"),
    ({"prompt": "a", "seconds": "four"}, "number"),
    ({"prompt": "a", "seed": -1}, "seed"),
    ({"prompt": "a", "seed": 2**40}, "seed"),
    ({"prompt": "a", "guidance": -1}, "guidance"),
    ({"prompt": "a", "steps": "a,b"}, "integers like 45,5"),
    ({"prompt": "a", "steps": [0]}, "between 1 and 200"),
    ({"prompt": "a", "steps": [1000, 5]}, "between 1 and 200"),
    ({"prompt": "a", "steps": []}, "steps"),
    ({"prompt": "a", "steps": list(range(1, 20))}, "steps"),
    ({"prompt": "a", "sflow_steps": 0}, "sflow_steps"),
    ({"prompt": "a", "joints": "yes"}, "joints"),
    ({"prompt": "a", "actor": 12}, "actor"),
    ([1, 2], "JSON object"),
    ("just text", "JSON object"),
]


@pytest.mark.parametrize("body, needle", BAD)
def test_bad_fields_are_400_with_one_line(server, body, needle):
    base, _ = server
    status, answer = as_json(request(base, "/api/generate", body))
    assert status == 400, answer
    assert needle in answer["error"] and "\n" not in answer["error"]
    assert "Traceback" not in answer["error"]


def test_bad_requests_and_limits(server):
    base, _ = server
    cases = [
        (
            request(
                base,
                "/api/generate",
                raw=b"{not json",
                headers={"Content-Type": "application/json"},
            ),
            400,
            "not valid JSON",
        ),
        (
            request(
                base,
                "/api/generate",
                raw=b'{"prompt": "a"}',
                headers={"Content-Type": "text/plain"},
            ),
            415,
            "JSON",
        ),
        (
            request(
                base,
                "/api/generate",
                raw=b" " * (MAX_JSON_BYTES + 1),
                headers={"Content-Type": "application/json"},
            ),
            413,
            "larger than",
        ),
        (
            request(
                base,
                "/api/generate",
                raw=b'{"prompt":"a","seconds":NaN}',
                headers={"Content-Type": "application/json"},
            ),
            400,
            "number",
        ),
        (
            request(base, "/api/generate", {"prompt": "a", "actor": "a999", "people": 2}),
            404,
            "upload it again",
        ),
        (request(base, "/api/nothing"), 404, "no such page"),
        (request(base, "/api/generate"), 405, "not allowed"),
        (request(base, "/api/health", method="DELETE"), 405, "not allowed"),
        (request(base, "/api/scenes/s999"), 404, "no scene"),
        (request(base, "/api/scenes/s999/mp4", method="POST", raw=b""), 404, "no scene"),
        (request(base, "/files/s1/other.glb"), 404, "no file"),
        (request(base, "/api/health", headers={"Host": "evil.example:80"}), 403, "not allowed"),
    ]
    for answer, want, needle in cases:
        status, body = as_json(answer)
        assert status == want and needle in body["error"], (want, body)


def test_reroll_makes_a_new_scene_with_the_others_as_they_were(server, scene):
    """POST /api/reroll: a new scene in the history whose other people are the stored
    scene's bit for bit (its NPZ), person 2 new; bad fields are one-line 4xx answers."""
    base, _ = server
    status, again = as_json(request(base, "/api/reroll",
                                    {"scene": scene["id"], "person": 2, "seed": 11}))  # fmt: skip
    assert status == 200, again
    assert again["id"] != scene["id"] and again["rerolled_from"] == scene["id"]
    assert again["reroll"] == {"person": 2, "seed": 11} and again["seed"] == scene["seed"]
    files = []
    for s in (scene, again):
        with np.load(io.BytesIO(request(base, s["files"]["npz"])[2])) as z:
            files.append({k: z[k] for k in ("joints", "rotations", "root")})
    for key in ("joints", "rotations", "root"):
        assert np.array_equal(files[0][key][[0, 2]], files[1][key][[0, 2]]), key
    assert not np.allclose(files[0]["joints"][1], files[1]["joints"][1])
    status, listed = as_json(request(base, "/api/scenes"))
    assert again["id"] in [s["id"] for s in listed["scenes"]]
    for body, code, needle in (
        ({"scene": scene["id"], "person": 4}, 400, "has 3 people, no person 4"),
        ({"scene": scene["id"]}, 400, "'person' is required"),
        ({"scene": scene["id"], "person": 1, "seed": -1}, 400, "'seed' must be between"),
        ({"scene": "s999", "person": 1}, 404, "no scene 's999'"),
        ({"scene": scene["id"], "person": 1, "extra": 1}, 400, "unknown field 'extra'"),
        ([1, 2], 400, "JSON object"),
    ):
        status, answer = as_json(request(base, "/api/reroll", body))
        assert status == code and needle in answer["error"], (body, answer)
        assert "\n" not in answer["error"]
    assert request(base, "/api/reroll")[0] == 405


def test_missing_content_length_is_411(server):
    import http.client

    base, _ = server
    conn = http.client.HTTPConnection(base.removeprefix("http://"), timeout=120)
    conn.putrequest("POST", "/api/generate")
    conn.putheader("Content-Type", "application/json")
    conn.endheaders()
    answer = conn.getresponse()
    assert answer.status == 411 and "Content-Length" in json.loads(answer.read())["error"]
    conn.close()


def test_react_upload_keeps_the_actor(server):
    base, _ = server
    status, actor = as_json(request(base, "/api/upload?name=bow.bvh", raw=BOW.read_bytes()))
    assert status == 200 and actor["people"] == 1 and actor["seconds"] > 1, actor
    status, out = as_json(
        request(
            base,
            "/api/generate",
            {
                "prompt": "One person bows and the other bows back.",
                "people": 2,
                "seconds": 2,
                "actor": actor["actor"],
            },
        )
    )
    assert status == 200, out
    from umf.data.motion_file import load_motion

    want = load_motion(BOW).joints[0, :60]  # 61 actor frames make 60 feature frames
    np.testing.assert_allclose(np.array(out["joints"])[0], want, atol=2e-3)
    bad = [
        (request(base, "/api/upload?name=notes.txt", raw=b"hello"), 415, ".bvh or .npz"),
        (request(base, "/api/upload", raw=b"hello"), 400, "name the file"),
        (request(base, "/api/upload?name=x.bvh", raw=b"HIERARCHY\nnonsense"), 400, "x.bvh"),
        (request(base, "/api/upload?name=x.npz", raw=b"PK\x03\x04garbage"), 400, "x.npz"),
        (
            request(base, "/api/generate", {"prompt": "a", "people": 1, "actor": actor["actor"]}),
            400,
            "between 2 and 16",
        ),
        (
            request(
                base,
                "/api/generate",
                {"prompt": "a", "people": 2, "actor": actor["actor"], "actor_person": 2},
            ),
            400,
            "no person 2",
        ),
        (
            request(
                base,
                "/api/generate",
                {"prompt": "a", "people": 2, "actor": actor["actor"], "start": 3000},
            ),
            400,
            "outside",
        ),
    ]
    for answer, want, needle in bad:
        status, body = as_json(answer)
        assert status == want and needle in body["error"], (want, body)
        assert "/tmp" not in body["error"]  # the server's paths stay private


def test_mp4_is_encoded_in_the_background_with_progress(server):
    base, _ = server
    status, out = as_json(
        request(
            base,
            "/api/generate",
            {"prompt": "A person waves.", "people": 2, "seconds": 0.5, "joints": False},
        )
    )
    status, video = as_json(request(base, out["files"]["mp4"], method="POST", raw=b""))
    assert status in (200, 202) and video["state"] in ("running", "done")
    deadline = time.time() + 600
    while video["state"] == "running" and time.time() < deadline:
        assert 0 <= video["done"] <= video["total"] == 15
        time.sleep(0.2)
        status, video = as_json(request(base, out["files"]["mp4"]))
    assert video["state"] == "done", video
    status, headers, data = request(base, video["url"])
    assert status == 200 and headers["Content-Type"] == "video/mp4" and data[4:8] == b"ftyp"


def test_a_model_that_fails_to_load_is_a_503(tmp_path):
    def broken():
        raise UMFError("model not found: /nowhere")

    app = App(ModelHolder(broken), None, workdir=tmp_path)
    httpd = start_in_thread(app)
    base = f"http://127.0.0.1:{httpd.server_address[1]}"
    try:
        status, body = as_json(request(base, "/api/generate", {"prompt": "a"}))
        assert status == 503 and "model not found: /nowhere" in body["error"]
        status, health = as_json(request(base, "/api/health"))
        assert health["model"]["state"] == "error" and not health["three"]
        status, body = as_json(request(base, "/vendor/three/build/three.module.js"))
        assert status == 404 and "three@" in body["error"]
    finally:
        httpd.shutdown()
        httpd.server_close()


def test_view_files_become_scenes(scene, server, tmp_path):
    base, app = server
    npz = tmp_path / "mine.npz"
    npz.write_bytes(request(base, scene["files"]["npz"])[2])
    record = add_motion_file(app.scenes, npz)
    assert record.people == 3 and set(record.files) == {"glb", "npz", "bvh"}
    glb = tmp_path / "mine.glb"
    glb.write_bytes(request(base, scene["files"]["glb"])[2])
    record = add_glb_file(app.scenes, glb)
    assert record.people == 3 and record.frames == 60 and record.text.startswith("Three")
    assert set(record.summary()["files"]) == {"glb"}
    (tmp_path / "bad.glb").write_bytes(b"glTF-not-really")
    with pytest.raises(UMFError, match=r"not a glTF 2\.0 binary"):
        add_glb_file(app.scenes, tmp_path / "bad.glb")


def run_umf(monkeypatch, capsys, *args: str) -> tuple[int, str]:
    """Exit code and stderr of the `umf` console script, run in-process (fast)."""
    from umf.cli.main import run

    monkeypatch.setattr(sys, "argv", ["umf", *args])
    with pytest.raises(SystemExit) as exit_:
        run()
    return exit_.value.code, capsys.readouterr().err


def test_cli_errors_are_one_line(tmp_path, monkeypatch, capsys):
    code, err = run_umf(monkeypatch, capsys, "view", str(tmp_path / "missing.npz"))
    assert code == 1 and err == f"umf: error: file not found: {tmp_path}/missing.npz\n"
    (tmp_path / "notes.txt").write_text("hi")
    code, err = run_umf(monkeypatch, capsys, "view", str(tmp_path / "notes.txt"))
    assert code == 1 and "use .npz, .glb or .bvh" in err and err.count("\n") == 1
    monkeypatch.setenv("UMF_THREE_DIR", str(tmp_path))
    code, err = run_umf(monkeypatch, capsys, "serve", "--port", "0")
    assert code == 1 and err.count("\n") == 1
    assert "three.js is missing" in err and "npm install" in err
