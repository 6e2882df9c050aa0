"""Hostile input against every door of umf: the server, the CLI readers and `data prepare`.

    python research/hostile_sweep.py [--out results/hardening-20261202] [--quick] [--server-only]

Builds hostile motion files (BVH that declare millions of frames, zip bombs, wrong units,
NaN, truncated, junk ...) and hostile requests (cross-site posts, Host tricks, slow clients,
deep JSON, lone surrogates ...), then sends each through:
- a real `umf serve` (bundled model, loaded lazily): upload, react, the API;
- `umf react --actor FILE`, `umf reroll FILE` and `umf view FILE --no-open`;
- `umf data prepare --mocap DIR` over all the files at once.
A case passes when umf answers with one line (CLI: a non-zero exit and one `error:` line, or
a clean success; server: a 2xx/4xx JSON line) and never a traceback or a 5xx, and the server
still answers afterwards. The server's peak resident memory (VmHWM) is read from /proc
after the upload cases and at the end. Writes ``OUT/sweep.json`` and ``OUT/README.md``.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
UMF = [sys.executable, "-m", "umf"]
CLIP = ROOT / "tests" / "clips" / "dataset-2_raise-up-both-hands_normal_001.bvh"


# ------------------------------------------------------------------ hostile files
def _bvh_header(joints: int = 1, channels: bool = True) -> str:
    ch = (
        "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
        if channels
        else "CHANNELS 0"
    )
    out = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0", ch]
    for k in range(joints - 1):
        out += [f"JOINT j{k}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    out += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * joints
    return "\n".join(out) + "\n"


def _npz(joints, compressed: bool = False, **extra) -> bytes:
    import io

    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, joints=joints, **extra)
    return buf.getvalue()


def hostile_files(quick: bool) -> dict[str, bytes]:
    """name -> bytes. Valid files are included too: they must still be read."""
    from umf.data.motion_file import load_motion

    real = load_motion(CLIP).joints  # (1, T, 22, 3) metres, 30 fps
    good_bvh = CLIP.read_bytes()
    text = good_bvh.decode()
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    frames_line = next(i for i, ln in enumerate(lines) if ln.startswith("Frames"))
    body = "\n".join(lines[frames_line + 2 :])

    def with_values(word: str) -> bytes:  # the motion with 40 of its numbers made ``word``
        frames = "\n".join(lines[: frames_line + 2])
        return (head + "MOTION\n" + frames + "\n" + body.replace("0.", word, 40)).encode()

    long = np.concatenate([real] * (18000 // real.shape[1] + 1), axis=1)[:, :18000]
    files: dict[str, bytes] = {
        "valid.bvh": good_bvh,
        "valid.npz": _npz(real, fps=np.float32(30)),
        "valid-4-people-10-min.npz": _npz(
            np.repeat(long, 4, 0)[:, : (18000 if not quick else 3000)]
        ),
        "no-channels-100k-frames.bvh": (
            _bvh_header(1, False) + "MOTION\nFrames: 100000\nFrame Time: 0.0333\n" + "\n" * 10
        ).encode(),
        "no-channels-10M-frames.bvh": (
            _bvh_header(1, False) + "MOTION\nFrames: 10000000\nFrame Time: 0.0333\n"
        ).encode(),
        "declares-10M-frames.bvh": (
            head + "MOTION\nFrames: 10000000\nFrame Time: 0.0333\n" + body
        ).encode(),
        "declares-2-frames-holds-more.bvh": (
            head + "MOTION\nFrames: 2\nFrame Time: 0.0333\n" + body
        ).encode(),
        "2000-joints.bvh": (
            _bvh_header(2000)
            + "MOTION\nFrames: 2\nFrame Time: 0.0333\n"
            + ("0 " * (6 + 3 * 1999) + "\n") * 2
        ).encode(),
        "truncated.bvh": good_bvh[: len(good_bvh) // 2],
        "header-only.bvh": head.encode(),
        "nan-values.bvh": with_values("nan"),
        "words-for-numbers.bvh": with_values("abc"),
        "frames-negative.bvh": (head + "MOTION\nFrames: -5\nFrame Time: 0.0333\n").encode(),
        "frames-words.bvh": (head + "MOTION\nFrames: many\nFrame Time: 0.0333\n").encode(),
        "frame-time-zero.bvh": (
            head + "MOTION\nFrames: 10\nFrame Time: 0\n" + "\n".join(body.splitlines()[:10])
        ).encode(),
        "frame-time-negative.bvh": (
            head + "MOTION\nFrames: 10\nFrame Time: -0.03\n" + "\n".join(body.splitlines()[:10])
        ).encode(),
        "unbalanced-braces.bvh": text.replace("}", "", 3).encode(),
        "crlf.bvh": text.replace("\n", "\r\n").encode(),
        "utf16.bvh": text.encode("utf-16"),
        "binary-junk.bvh": bytes(np.random.default_rng(0).integers(0, 256, 50_000, np.uint8)),
        "empty.bvh": b"",
        "one-frame.bvh": (
            head + "MOTION\nFrames: 1\nFrame Time: 0.0333\n" + body.splitlines()[0]
        ).encode(),
        "unknown-skeleton.bvh": re.sub(r"(JOINT|ROOT) (\S+)", r"\1 bone_\2", text).encode(),
        "in-centimetres.bvh": re.sub(
            r"OFFSET ([-\d.e]+) ([-\d.e]+) ([-\d.e]+)",
            lambda m: "OFFSET " + " ".join(f"{float(v) * 100:g}" for v in m.groups()),
            text,
        ).encode(),
        "zip-bomb.npz": _npz(np.zeros((8, 150_000, 22, 3), np.float32), compressed=True),
        "2000-frames-at-1-fps.npz": _npz(np.repeat(real[:, :1], 2000, 1), fps=np.float32(1)),
        "588-s-at-3.4-fps.npz": _npz(np.repeat(real[:, :1], 2000, 1) + 0, fps=np.float32(3.4)),
        "in-centimetres.npz": _npz(real * 100),
        "in-millimetres.npz": _npz(real * 1000),
        "in-inches.npz": _npz(real / 0.0254),
        "zero-people.npz": _npz(np.zeros((0, 100, 22, 3), np.float32)),
        "zero-frames.npz": _npz(np.zeros((1, 0, 22, 3), np.float32)),
        "one-frame.npz": _npz(real[:, :1]),
        "all-zero.npz": _npz(np.zeros((1, 100, 22, 3), np.float32)),
        "nan.npz": _npz(np.where(np.arange(real.size).reshape(real.shape) % 7 == 0, np.nan, real)),
        "inf.npz": _npz(np.where(np.arange(real.size).reshape(real.shape) % 7 == 0, np.inf, real)),
        "wrong-shape.npz": _npz(np.zeros((100, 24, 3), np.float32)),
        "flat-shape.npz": _npz(np.zeros((100, 66), np.float32)),
        "strings.npz": _npz(np.array(["a", "b"])),
        "int-joints.npz": _npz((real * 1000).astype(np.int64)),
        "float16.npz": _npz(real.astype(np.float16)),
        "fps-zero.npz": _npz(real, fps=np.float32(0)),
        "fps-nan.npz": _npz(real, fps=np.float32(np.nan)),
        "fps-huge.npz": _npz(real, fps=np.float32(1e9)),
        "fps-words.npz": _npz(real, fps=np.array("fast")),
        "fps-array.npz": _npz(real, fps=np.arange(3, dtype=np.float32)),
        "text-array.npz": _npz(real, text=np.arange(5)),
        "no-joints.npz": _npz(np.zeros(3), compressed=True).replace(b"joints", b"jjjjjj"),
        "not-a-zip.npz": b"PK\x03\x04" + b"\x00" * 500,
        "truncated.npz": _npz(real)[:2000],
        "a-bvh-named-npz.npz": good_bvh,
    }
    try:  # a pickled object array: must be refused, never unpickled
        import io

        buf = io.BytesIO()
        np.savez(buf, joints=np.array([{"a": 1}], dtype=object))
        files["pickled-object.npz"] = buf.getvalue()
    except Exception:  # numpy refusing to write it is as good
        pass
    return files


# ------------------------------------------------------------------ the server
def _rss(pid: int) -> tuple[float, float]:
    """(current, peak) resident memory of ``pid`` in MB."""
    status = Path(f"/proc/{pid}/status").read_text()
    get = lambda key: float(re.search(rf"{key}:\s+(\d+)", status).group(1)) / 1024  # noqa: E731
    return get("VmRSS"), get("VmHWM")


class Server:
    def __init__(self, workdir: Path) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [*UMF, "serve", "--port", "0", "--no-open"],
            cwd=workdir,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        line = self.proc.stdout.readline()
        m = re.search(r"http://[^:]+:(\d+)", line)
        if not m:
            raise SystemExit(f"umf serve did not start: {line!r} {self.proc.stderr.read()}")
        self.port = int(m.group(1))
        self.cookie = ""

    def ask(self, method, path, body=b"", headers=None, timeout=120):
        """One request as the page's browser (its session cookie kept)."""
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        hdrs = {"Host": f"localhost:{self.port}", **({"Cookie": self.cookie} if self.cookie
                                                      else {}), **(headers or {})}  # fmt: skip
        conn.request(method, path, body=body or None, headers=hdrs)
        r = conn.getresponse()
        data = r.read()
        conn.close()
        if r.getheader("Set-Cookie") and not self.cookie:
            self.cookie = r.getheader("Set-Cookie").split(";")[0]
        return r.status, dict(r.getheaders()), data

    def alive(self) -> bool:
        try:
            return self.ask("GET", "/api/health", timeout=30)[0] == 200
        except OSError:
            return False

    def stop(self) -> str:
        self.proc.terminate()
        try:
            _, err = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return err


def judge_http(answer) -> tuple[bool, str]:
    """Pass: a JSON answer that is not a 5xx, one line of error when it is an error."""
    status, headers, data = answer
    if status >= 500:
        return False, f"{status} {data[:120]!r}"
    if headers.get("Content-Type") != "application/json":
        return status < 400, f"{status} {headers.get('Content-Type')}"
    doc = json.loads(data)
    if status >= 400:
        return "\n" not in doc.get("error", "\n"), f"{status} {doc.get('error', '')[:110]}"
    return True, f"{status}"


def server_cases(srv: Server, files: dict[str, bytes]) -> list[dict]:
    rows = []

    def case(kind, name, fn):
        t0 = time.perf_counter()
        try:
            ok, said = fn()
        except Exception as exc:  # a dropped connection is a result too
            ok, said = False, f"{type(exc).__name__}: {exc}"
        ok = ok and srv.alive()
        rss, peak = _rss(srv.proc.pid)
        rows.append(
            {
                "door": "server",
                "kind": kind,
                "case": name,
                "ok": ok,
                "said": said,
                "seconds": round(time.perf_counter() - t0, 2),
                "rss_mb": round(rss),
                "peak_mb": round(peak),
            }
        )
        print(f"{'ok  ' if ok else 'FAIL'} server {kind:8s} {name:34s} {said[:90]}", flush=True)

    octet = {"Content-Type": "application/octet-stream"}
    actors = {}
    for name, data in files.items():

        def up(name=name, data=data):
            answer = srv.ask("POST", f"/api/upload?name={name}", data, octet)
            if answer[0] == 200:
                actors[name] = json.loads(answer[2])["actor"]
            return judge_http(answer)

        case("upload", name, up)
    jsonh = {"Content-Type": "application/json"}

    def gen(body, h=jsonh):
        return lambda: judge_http(
            srv.ask(
                "POST",
                "/api/generate",
                json.dumps(body).encode(),
                h,
            )
        )

    for name, aid in list(actors.items())[:3]:
        case(
            "react",
            name,
            gen(
                {
                    "prompt": "A person bows.",
                    "people": 2,
                    "actor": aid,
                    "seconds": 2,
                    "joints": False,
                }
            ),
        )
    case(
        "react",
        "start past the end",
        gen(
            {"prompt": "x", "people": 2, "start": 9000, "actor": next(iter(actors.values()), "a1")}
        ),
    )
    case("react", "someone else's actor id", gen({"prompt": "x", "people": 2, "actor": "a999"}))

    def raw(method, path, body=b"", h=None):
        return lambda: judge_http(srv.ask(method, path, body, h))

    body = json.dumps({"prompt": "A person waves.", "people": 1, "seconds": 1}).encode()
    api = {
        "no content type": raw("POST", "/api/generate", body, {}),
        "text/plain": raw("POST", "/api/generate", body, {"Content-Type": "text/plain"}),
        "form": raw(
            "POST", "/api/generate", body, {"Content-Type": "application/x-www-form-urlencoded"}
        ),
        "evil origin": raw(
            "POST", "/api/generate", body, {**jsonh, "Origin": "https://evil.example"}
        ),
        "null origin": raw("POST", "/api/generate", body, {**jsonh, "Origin": "null"}),
        "upload as text/plain": raw(
            "POST", "/api/upload?name=a.bvh", files["valid.bvh"], {"Content-Type": "text/plain"}
        ),
        "host evil.com": raw("GET", "/api/scenes", b"", {"Host": "evil.com"}),
        "host localhost@evil": raw(
            "GET", "/api/scenes", b"", {"Host": f"localhost:{srv.port}@evil.com"}
        ),
        "host nip.io": raw("GET", "/api/scenes", b"", {"Host": "127.0.0.1.nip.io"}),
        "host 0.0.0.0": raw("GET", "/api/scenes", b"", {"Host": "0.0.0.0"}),
        "host empty": raw("GET", "/api/scenes", b"", {"Host": ""}),
        "json nested 30000": raw("POST", "/api/generate", b"[" * 30000 + b"]" * 30000, jsonh),
        "json a list": raw("POST", "/api/generate", b"[1, 2]", jsonh),
        "json not utf-8": raw("POST", "/api/generate", b'{"prompt": "\xff\xfe"}', jsonh),
        "json too large": raw("POST", "/api/generate", b" " * 70_000 + b"{}", jsonh),
        "lone surrogate": gen({"prompt": "\ud800 hi", "people": 1, "seconds": 1}),
        "prompt empty": gen({"prompt": "", "people": 1}),
        "prompt 100 KB": raw(
            "POST", "/api/generate", json.dumps({"prompt": "a" * 60_000}).encode(), jsonh
        ),
        "people 0": gen({"prompt": "a", "people": 0}),
        "people 17": gen({"prompt": "a", "people": 17}),
        "people '3'": gen({"prompt": "a", "people": "3"}),
        "people true": gen({"prompt": "a", "people": True}),
        "seconds nan": raw("POST", "/api/generate", b'{"prompt": "a", "seconds": NaN}', jsonh),
        "seconds 1e308": gen({"prompt": "a", "seconds": 1e308}),
        "seed -1": gen({"prompt": "a", "seed": -1}),
        "seed 2^64": gen({"prompt": "a", "seed": 2**64}),
        "steps [1]": gen({"prompt": "a", "people": 1, "seconds": 1, "steps": [1]}),
        "steps [0]": gen({"prompt": "a", "steps": [0]}),
        "steps 10^6": gen({"prompt": "a", "steps": [10**6]}),
        "unknown field": gen({"prompt": "a", "evil": 1}),
        "generate 1 person": gen({"prompt": "A person waves.", "people": 1, "seconds": 1}),
        "no content length": lambda: _no_length(srv),
        "path ../": raw("GET", "/files/../../etc/passwd"),
        "path %2e%2e": raw("GET", "/files/%2e%2e/%2e%2e/etc/passwd"),
        "static ..": raw("GET", "/static/..%2fserver.py"),
        "vendor ..": raw("GET", "/vendor/three/../../../etc/passwd"),
        "scene s999": raw("GET", "/api/scenes/s999"),
        "mp4 of s999": raw("POST", "/api/scenes/s999/mp4", b"", jsonh),
        "OPTIONS": raw("OPTIONS", "/api/generate"),
        "PATCH": raw("PATCH", "/api/generate", b"{}", jsonh),
        "DELETE": raw("DELETE", "/api/scenes"),
        "HEAD": lambda: (srv.ask("HEAD", "/api/health")[0] < 500, "HEAD"),
        "URI 100 KB": raw("GET", "/" + "a" * 100_000),
        "header 100 KB": raw("GET", "/api/health", b"", {"X-Big": "a" * 100_000}),
        "upload 21 MB": lambda: _declared_too_large(srv),
        "upload no name": raw("POST", "/api/upload", files["valid.bvh"], octet),
        "upload name CRLF": raw(
            "POST", "/api/upload?name=a%0d%0aSet-Cookie:x.bvh", files["valid.bvh"], octet
        ),
        "upload .exe": raw("POST", "/api/upload?name=a.exe", b"MZ", octet),
        "slow client": lambda: _slow_client(srv),
        "40 idle connections": lambda: _many_connections(srv, 40),
    }
    for name, fn in api.items():
        case("api", name, fn)

    def reroll(body):
        return lambda: judge_http(srv.ask("POST", "/api/reroll", json.dumps(body).encode(), jsonh))

    answer = srv.ask("POST", "/api/generate", json.dumps(
        {"prompt": "Two people walk side by side.", "people": 2, "seconds": 1, "joints": False}
    ).encode(), jsonh)  # fmt: skip
    sid = json.loads(answer[2]).get("id", "s1") if answer[0] == 200 else "s1"
    rerolls = {
        "valid": reroll({"scene": sid, "person": 2, "seed": 3, "joints": False}),
        "person 0": reroll({"scene": sid, "person": 0}),
        "person 3 of 2": reroll({"scene": sid, "person": 3}),
        "person '1'": reroll({"scene": sid, "person": "1"}),
        "no person": reroll({"scene": sid}),
        "scene s999": reroll({"scene": "s999", "person": 1}),
        "scene a list": reroll({"scene": [sid], "person": 1}),
        "scene 100 KB id": reroll({"scene": "s" * 100_000, "person": 1}),
        "seed 2^64": reroll({"scene": sid, "person": 1, "seed": 2**64}),
        "unknown field": reroll({"scene": sid, "person": 1, "prompt": "x"}),
        "GET": raw("GET", "/api/reroll"),
        "text/plain": raw(
            "POST", "/api/reroll", b'{"scene": "s1", "person": 1}', {"Content-Type": "text/plain"}
        ),
    }
    for name, fn in rerolls.items():
        case("reroll", name, fn)
    return rows


def _no_length(srv: Server) -> tuple[bool, str]:
    with socket.create_connection(("127.0.0.1", srv.port), timeout=30) as s:
        s.sendall(
            f"POST /api/generate HTTP/1.1\r\nHost: localhost:{srv.port}\r\n"
            "Content-Type: application/json\r\n\r\n{}".encode()
        )
        data = s.recv(4096).decode(errors="replace")
    status = int(data.split()[1])
    return 400 <= status < 500 and "application/json" in data, data.splitlines()[0]


def _declared_too_large(srv: Server) -> tuple[bool, str]:
    """A 21 MB upload declared: refused from its Content-Length, before the body is read."""
    with socket.create_connection(("127.0.0.1", srv.port), timeout=30) as s:
        s.sendall(f"POST /api/upload?name=big.npz HTTP/1.1\r\nHost: localhost:{srv.port}\r\n"
                  "Content-Type: application/octet-stream\r\n"
                  f"Content-Length: {21 * 1024 * 1024}\r\n\r\n".encode())  # fmt: skip
        s.sendall(b"0" * 65536)
        data = s.recv(4096).decode(errors="replace")
    status = int(data.split()[1])
    return status == 413 and "application/json" in data, data.splitlines()[0]


def _slow_client(srv: Server) -> tuple[bool, str]:
    """One byte every 10 s: the server must give up on it at its 60 s deadline."""
    t0 = time.perf_counter()
    data = b""
    with socket.create_connection(("127.0.0.1", srv.port), timeout=90) as s:
        s.sendall(
            f"POST /api/generate HTTP/1.1\r\nHost: localhost:{srv.port}\r\n"
            "Content-Type: application/json\r\nContent-Length: 100\r\n\r\n".encode()
        )
        s.settimeout(10)
        try:
            while time.perf_counter() - t0 < 85:
                s.sendall(b" ")
                try:  # the server answers or closes: either ends the wait
                    data = s.recv(4096)
                    break
                except TimeoutError:
                    continue
        except OSError:
            pass
    took = time.perf_counter() - t0
    return took < 72, f"cut off after {took:.0f} s {data[:60]!r}"


def _many_connections(srv: Server, n: int) -> tuple[bool, str]:
    socks = []
    try:
        for _ in range(n):
            socks.append(socket.create_connection(("127.0.0.1", srv.port), timeout=10))
        time.sleep(0.5)
        answer = srv.ask("GET", "/api/health", timeout=10)
        return answer[0] in (200, 503), f"{n} idle open; health -> {answer[0]}"
    except OSError as exc:
        return True, f"refused past the cap ({type(exc).__name__})"
    finally:
        for s in socks:
            s.close()


# ------------------------------------------------------------------ the CLI
def judge_cli(proc: subprocess.CompletedProcess) -> tuple[bool, str]:
    out = (proc.stdout or "") + (proc.stderr or "")
    if "Traceback" in out:
        return False, "traceback: " + out.strip().splitlines()[-1][:100]
    if proc.returncode == 0:
        return True, "exit 0"
    errors = [ln for ln in (proc.stderr or "").splitlines()
              if re.match(r"(umf: )?error:", ln)]  # fmt: skip
    return len(errors) == 1, f"exit {proc.returncode}: " + (errors[0] if errors else out[-100:])


def view_case(path: Path, work: Path) -> tuple[bool, str]:
    """`umf view FILE`: a readable file is served (then stopped), any other is one line."""
    proc = subprocess.Popen(
        [*UMF, "view", str(path), "--no-open", "--port", "0"],
        cwd=work,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    line = proc.stdout.readline()
    if line.startswith("umf serve:"):
        proc.terminate()
        proc.communicate(timeout=30)
        return True, "served"
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        return False, "neither served nor refused in 120 s"
    return judge_cli(subprocess.CompletedProcess(proc.args, proc.returncode, line + out, err))


def cli_cases(files: dict[str, Path], work: Path, quick: bool) -> list[dict]:
    rows = []

    def case(kind, name, argv, timeout=300):
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(
                [*UMF, *argv],
                capture_output=True,
                text=True,
                timeout=timeout,
                cwd=work,
                env={**os.environ, "OMP_NUM_THREADS": "1"},
            )
            ok, said = judge_cli(proc)
        except subprocess.TimeoutExpired:
            proc, ok, said = None, False, f"still running after {timeout} s"
        rows.append(
            {
                "door": "cli",
                "kind": kind,
                "case": name,
                "ok": ok,
                "said": said,
                "seconds": round(time.perf_counter() - t0, 2),
            }
        )
        print(f"{'ok  ' if ok else 'FAIL'} cli    {kind:8s} {name:34s} {said[:90]}", flush=True)
        return proc

    names = list(files) if not quick else [n for n in files if not n.startswith("valid-4")]
    for name in names:
        case(
            "react",
            name,
            [
                "react",
                "A person bows.",
                "--actor",
                str(files[name]),
                "--people",
                "2",
                "--seconds",
                "1",
                "--out",
                str(work / "react"),
                "--format",
                "npz",
            ],
        )
    for name in names:
        t0 = time.perf_counter()
        ok, said = view_case(files[name], work)
        rows.append(
            {
                "door": "cli",
                "kind": "view",
                "case": name,
                "ok": ok,
                "said": said,
                "seconds": round(time.perf_counter() - t0, 2),
            }
        )
        print(f"{'ok  ' if ok else 'FAIL'} cli    view     {name:34s} {said[:90]}", flush=True)
    for name in names:  # a scene file of any kind as the scene to re-roll
        case("reroll", name, ["reroll", str(files[name]), "--person", "1", "--out",
                              str(work / "reroll"), "--format", "npz"])  # fmt: skip
    lib = work / "library"
    lib.mkdir(exist_ok=True)
    for name in names:
        (lib / name).write_bytes(files[name].read_bytes())
    proc = case(
        "prepare",
        "all files in one --mocap",
        ["data", "prepare", "--mocap", str(lib), "--out", str(work / "corpus")],
    )
    if proc is not None:
        report = work / "corpus" / "manifest.json"
        rows[-1]["report"] = (
            json.loads(report.read_text()).get("problems") if report.exists() else None
        )
    flags = {
        "generate --steps 1": ["generate", "a", "--steps", "1", "--out", str(work / "g")],
        "generate lone surrogate": ["generate", "\udc80bad", "--out", str(work / "g")],
        "generate --people 0": ["generate", "a", "--people", "0"],
        "generate --seconds nan": ["generate", "a", "--seconds", "nan"],
        "generate --out a file": ["generate", "a", "--out", str(files["valid.bvh"])],
        "react missing file": ["react", "a", "--actor", str(work / "nope.bvh")],
        "react --start past the end": [
            "react",
            "a",
            "--actor",
            str(files["valid.bvh"]),
            "--start",
            "900",
        ],
        "react --actor-person 3": [
            "react",
            "a",
            "--actor",
            str(files["valid.bvh"]),
            "--actor-person",
            "3",
        ],
        "reroll --person 0": ["reroll", str(files["valid.npz"]), "--person", "0"],
        "reroll --seed -1": ["reroll", str(files["valid.npz"]), "--person", "1", "--seed", "-1"],
        "reroll missing file": ["reroll", str(work / "nope.npz"), "--person", "1"],
        "view a .txt": ["view", str(lib / "x.txt")],
        "data info on junk": ["data", "info", str(lib)],
        "train on junk corpus": ["train", "vae", "--corpus", str(lib), "--out", str(work / "t")],
    }
    (lib / "x.txt").write_text("hi")
    for name, argv in flags.items():
        case("flags", name, argv, timeout=120)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "hardening-20261202")
    ap.add_argument("--quick", action="store_true", help="smaller files, skip the long ones")
    ap.add_argument("--server-only", action="store_true", help="the server's cases alone")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="umf-sweep-") as tmp:
        work = Path(tmp)
        files = hostile_files(args.quick)
        paths = {}
        for name, data in files.items():
            paths[name] = work / "files" / name
            paths[name].parent.mkdir(exist_ok=True)
            paths[name].write_bytes(data)
        srv = Server(work)
        t0 = time.perf_counter()
        try:
            rows = server_cases(srv, files)
            upload_peak = max(r["peak_mb"] for r in rows if r["kind"] == "upload")
            _, peak = _rss(srv.proc.pid)
        finally:
            err = srv.stop()
        server_s = time.perf_counter() - t0
        if not args.server_only:
            rows += cli_cases(paths, work, args.quick)
    tracebacks = err.count("Traceback")
    for r in rows:  # the run's temporary folder is no one else's path
        r["said"] = r["said"].replace(str(work), "$WORK")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "server.log").write_text(err)  # what the server printed: its tracebacks too
    failed = [r for r in rows if not r["ok"]]
    summary = {
        "cases": len(rows),
        "passed": len(rows) - len(failed),
        "server_peak_mb_uploads": upload_peak,
        "server_peak_mb": round(peak),
        "server_log_tracebacks": tracebacks,
        "server_seconds": round(server_s),
        "failed": [f"{r['door']} {r['kind']} {r['case']}: {r['said']}" for r in failed],
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "sweep.json").write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    lines = [
        "# Hostile-input sweep",
        "",
        f"`python research/hostile_sweep.py` ({len(rows)} cases"
        f"{', --quick' if args.quick else ''}), {time.strftime('%Y-%m-%d')}, on this machine. "
        "A case passes when umf answers with one line (CLI: one `error:` line and exit 1/2, or a "
        "clean success; server: a 2xx/4xx JSON line), never a traceback or a 5xx, and the "
        "server still answers after it.",
        "",
        f"- passed: {summary['passed']} of {summary['cases']}",
        f"- server peak resident memory: {upload_peak} MB through the uploads, "
        f"{summary['server_peak_mb']} MB at the end (the model loaded for the "
        "generate cases)",
        f"- tracebacks in the server's log: {tracebacks}",
        "",
        "| door | kind | case | ok | what umf said | s |",
        "|---|---|---|---|---|---:|",
    ]
    for r in rows:
        said = r["said"].replace("|", "\\|").replace("\n", " ")[:140]
        lines.append(
            f"| {r['door']} | {r['kind']} | {r['case']} | {'yes' if r['ok'] else '**no**'}"
            f" | {said} | {r['seconds']} |"
        )
    (args.out / "README.md").write_text("\n".join(lines) + "\n")
    print(json.dumps(summary, indent=1))
    sys.exit(1 if failed or tracebacks else 0)


if __name__ == "__main__":
    main()
