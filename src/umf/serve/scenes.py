"""What `umf serve` keeps between requests: the model, the scenes of this session and their
files, uploaded actor motions, and MP4 encodings running in the background.

Everything lives in memory and in one temporary directory per server; old scenes are
dropped (files included) past a fixed count so a long session cannot fill the disk.
"""

from __future__ import annotations

import itertools
import json
import re
import shutil
import struct
import threading
import time
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from umf.errors import UMFError
from umf.serve.validate import RequestError

MAX_SCENES = 100
MAX_ACTORS = 20
MODEL_WAIT_S = 300.0  # how long a request waits for the model to finish loading
BUSY_WAIT_S = 60.0  # how long a request waits for another one's generation


def slug(text: str, limit: int = 40) -> str:
    """File-name stem from a prompt (what `umf generate` names its files)."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit] or "scene"


class ModelHolder:
    """The pipeline, loaded once in a background thread so the page can say "loading"."""

    def __init__(self, loader: Callable[[], Any] | None, pipeline: Any = None) -> None:
        self._loader = loader
        self._pipeline = pipeline
        self._error: str | None = None
        self._ready = threading.Event()
        self._started = threading.Lock()
        self._thread: threading.Thread | None = None
        self.generating = threading.Lock()
        self.load_seconds: float | None = None
        if pipeline is not None:
            self._ready.set()

    @property
    def state(self) -> str:
        """``idle`` (not asked yet), ``loading``, ``ready`` or ``error``."""
        if self._ready.is_set():
            return "error" if self._error else "ready"
        return "loading" if self._thread else "idle"

    def info(self) -> dict[str, Any]:
        name = getattr(self._pipeline, "name", None)
        return {"state": self.state, "name": name, "error": self._error,
                "load_seconds": self.load_seconds}  # fmt: skip

    def start(self) -> None:
        """Begin loading (once); returns at once."""
        with self._started:
            if self._thread is not None or self._ready.is_set():
                return
            self._thread = threading.Thread(target=self._load, name="umf-model", daemon=True)
            self._thread.start()

    def _load(self) -> None:
        begin = time.perf_counter()
        try:
            if self._loader is None:
                raise UMFError("no model to load")
            self._pipeline = self._loader()
            self._warm_up(self._pipeline)
        except UMFError as exc:
            self._error = str(exc)
        except Exception as exc:  # a broken install: report it, never a traceback
            self._error = f"the model could not be loaded ({type(exc).__name__}: {exc})"[:300]
        self.load_seconds = round(time.perf_counter() - begin, 2)
        self._ready.set()

    @staticmethod
    def _warm_up(pipeline: Any) -> None:
        """One tiny scene while the user is still typing: torch's first calls are slow
        (allocations, kernel choice), and the first click should not pay for them."""
        pipeline(["warm up"], num_people=2, seconds=1.0, seed=0)

    def get(self, timeout: float = MODEL_WAIT_S) -> Any:
        """The loaded pipeline; a RequestError (503) if it failed or is still loading."""
        self.start()
        if not self._ready.wait(timeout):
            raise RequestError("the model is still loading; try again shortly", 503)
        if self._error:
            raise RequestError(f"the model is not available: {self._error}", 503)
        return self._pipeline


@dataclass
class Video:
    """State of one scene's MP4 encoding, read by the page to show progress."""

    state: str = "idle"  # idle, running, done, error
    done: int = 0
    total: int = 0
    error: str | None = None


@dataclass
class SceneRecord:
    """One scene of the session: its parameters, joints and the files written for it."""

    id: str
    text: str
    joints: np.ndarray | None  # (N, T, 22, 3) or None for a GLB opened by `umf view`
    fps: float
    people: int
    frames: int
    params: dict[str, Any]
    folder: Path
    files: dict[str, str] = field(default_factory=dict)  # kind -> file name in folder
    video: Video = field(default_factory=Video)
    created: float = field(default_factory=time.time)
    session: str | None = None  # the browser session that made it; None: every session's

    def summary(self) -> dict[str, Any]:
        """What the API returns about the scene (without the joints)."""
        links = {kind: f"/files/{self.id}/{name}" for kind, name in self.files.items()}
        if self.joints is not None:
            links["mp4"] = f"/api/scenes/{self.id}/mp4"
        return {
            "id": self.id, "text": self.text, "people": self.people, "frames": self.frames,
            "fps": self.fps, "seconds": round(self.frames / self.fps, 3), **self.params,
            "files": links,
        }  # fmt: skip


def write_bvh_zip(scene: Any, path: Path, stem: str) -> Path:
    """One BVH per person (``Scene.save_bvh``) packed in a zip, for a single download."""
    folder = path.parent / f".{path.stem}-bvh"
    folder.mkdir(exist_ok=True)
    try:
        files = scene.save_bvh(folder / f"{stem}-p{{i}}.bvh")
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in files:
                zf.write(f, f.name)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return path


class SceneStore:
    """The session's scenes by id, oldest dropped first, each with a folder of files."""

    def __init__(self, root: Path, limit: int = MAX_SCENES) -> None:
        self.root = root
        self.limit = limit
        self._scenes: OrderedDict[str, SceneRecord] = OrderedDict()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()

    def new_record(self, text: str, joints: np.ndarray | None, fps: float, people: int,
                   frames: int, params: dict[str, Any]) -> SceneRecord:  # fmt: skip
        """An empty record with its own folder; :meth:`add` publishes it."""
        with self._lock:
            sid = f"s{next(self._ids)}"
        folder = self.root / sid
        folder.mkdir(parents=True)
        return SceneRecord(sid, text, joints, fps, people, frames, params, folder)

    def add(self, record: SceneRecord) -> SceneRecord:
        with self._lock:
            self._scenes[record.id] = record
            while len(self._scenes) > self.limit:
                _, old = self._scenes.popitem(last=False)
                shutil.rmtree(old.folder, ignore_errors=True)
        return record

    def get(self, sid: str, session: str | None = None) -> SceneRecord:
        """A scene of ``session`` (or one every session sees); another session's scene is
        answered as if it did not exist."""
        with self._lock:
            record = self._scenes.get(sid)
        if record is None or record.session not in (None, session):
            raise RequestError(f"no scene {sid!r} (it may have been dropped)", 404)
        return record

    def all(self, session: str | None = None) -> list[SceneRecord]:
        """The scenes ``session`` sees: its own and those shown to everyone."""
        with self._lock:
            return [r for r in self._scenes.values() if r.session in (None, session)]

    def add_scene(
        self, scene: Any, params: dict[str, Any], session: str | None = None
    ) -> SceneRecord:
        """A generated :class:`umf.pipeline.Scene` with its GLB, NPZ and BVH zip written."""
        if isinstance(scene.meta.get("coverage"), dict):
            params = {**params, "coverage": scene.meta["coverage"]}
        if isinstance(scene.meta.get("person_coverage"), list):
            params = {**params, "person_coverage": scene.meta["person_coverage"]}
        if isinstance(scene.meta.get("take"), dict):  # a couple finished from a real take
            params = {**params, "take": scene.meta["take"]}
        record = self.new_record(scene.text, scene.joints, float(scene.fps), scene.num_people,
                                 scene.num_frames, params)  # fmt: skip
        record.session = session
        stem = slug(scene.text)
        record.files["glb"] = scene.save_glb(record.folder / f"{stem}.glb").name
        record.files["npz"] = scene.save_npz(record.folder / f"{stem}.npz").name
        record.files["bvh"] = write_bvh_zip(scene, record.folder / f"{stem}-bvh.zip", stem).name
        return self.add(record)

    def start_video(self, record: SceneRecord) -> Video:
        """Encode the scene's MP4 in a background thread (once); returns its state."""
        with self._lock:
            if record.joints is None:
                raise RequestError("this scene has no joints to render (a GLB file)", 409)
            if record.video.state in ("running", "done"):
                return record.video
            record.video = Video(state="running", total=record.frames)
        thread = threading.Thread(target=self._encode, args=(record,), daemon=True)
        thread.start()
        return record.video

    def _encode(self, record: SceneRecord) -> None:
        from umf.render import render_animation

        def on_frame(done: int, total: int) -> None:
            record.video.done, record.video.total = done, total

        name = f"{slug(record.text)}.mp4"
        try:
            render_animation(record.joints, record.folder / name, caption=record.text,
                             fps=record.fps, progress=False, on_frame=on_frame)  # fmt: skip
        except Exception as exc:  # reported to the page; the server goes on
            record.video.error = f"{type(exc).__name__}: {exc}"[:300]
            record.video.state = "error"
            return
        record.files["mp4"] = name
        record.video.state = "done"


class ActorStore:
    """Uploaded motions (``open_motion`` results, not yet resampled) by id, for react."""

    def __init__(self, limit: int = MAX_ACTORS) -> None:
        self.limit = limit
        self._motions: OrderedDict[str, Any] = OrderedDict()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()

    def add(self, motion: Any, session: str | None = None) -> str:
        with self._lock:
            aid = f"a{next(self._ids)}"
            self._motions[aid] = (session, motion)
            while len(self._motions) > self.limit:
                self._motions.popitem(last=False)
        return aid

    def get(self, aid: str, session: str | None = None) -> Any:
        with self._lock:
            owner, motion = self._motions.get(aid, (None, None))
        if motion is None or owner not in (None, session):
            raise RequestError(f"no uploaded motion {aid!r}; upload it again", 404)
        return motion


def read_glb_json(path: Path) -> dict[str, Any]:
    """The JSON chunk of a GLB file (header checked), for `umf view FILE.glb`."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data) if len(data) >= 12 else (b"", 0, 0)
    if magic != b"glTF" or version != 2 or length != len(data) or len(data) < 20:
        raise UMFError(f"{path}: not a glTF 2.0 binary (.glb) file")
    size, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON":
        raise UMFError(f"{path}: the GLB has no JSON chunk first")
    try:
        return json.loads(data[20 : 20 + size].decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise UMFError(f"{path}: corrupt GLB JSON ({exc})") from exc


def add_glb_file(store: SceneStore, path: Path) -> SceneRecord:
    """A GLB scene as it is: the viewer plays its animation; no joints, so no other files."""
    doc = read_glb_json(path)
    if not isinstance(doc, dict):
        raise UMFError(f"{path}: the GLB's JSON is not an object")
    asset = doc.get("asset") if isinstance(doc.get("asset"), dict) else {}
    extras = asset.get("extras") if isinstance(asset.get("extras"), dict) else {}
    try:  # umf's own extras; any other writer's are optional, and wrong ones are refused
        fps = float(extras.get("fps", 30.0))
    except (TypeError, ValueError):
        raise UMFError(
            f"{path}: asset.extras.fps {extras.get('fps')!r:.40} is not a number"
        ) from None
    if not 1.0 <= fps <= 1000.0:  # NaN fails too
        raise UMFError(f"{path}: asset.extras.fps {fps:g} is not a frame rate (1-1000)")
    try:
        sampler = doc["animations"][0]["samplers"][0]
        frames = int(doc["accessors"][sampler["input"]]["count"])
    except (KeyError, IndexError, TypeError, ValueError):
        frames = 1
    named = extras.get("people")
    skins = doc.get("skins")
    people = len(named) if isinstance(named, list) else len(skins) if isinstance(skins, list) else 0
    seed = extras.get("seed") if isinstance(extras.get("seed"), int) else None
    text = extras.get("text") if isinstance(extras.get("text"), str) else path.stem
    record = store.new_record(text or path.stem, None, fps, people, max(frames, 1),
                              {"seed": seed, "source": path.name})  # fmt: skip
    shutil.copyfile(path, record.folder / path.name)
    record.files["glb"] = path.name
    return store.add(record)


def add_motion_file(store: SceneStore, path: Path) -> SceneRecord:
    """A .npz or .bvh motion (``load_motion``) with a GLB and BVH zip made from its joints;
    the NPZ download is the file itself (a .bvh gets an NPZ of its joints)."""
    from umf.data.motion_file import FPS, load_motion
    from umf.io import save_npz_atomic

    scene = load_motion(path)
    joints = scene.joints
    text = scene.text = scene.text or path.stem
    record = store.new_record(text, joints, FPS, scene.num_people, scene.num_frames,
                              {"source": path.name})  # fmt: skip
    stem = slug(text)
    record.files["glb"] = scene.save_glb(record.folder / f"{stem}.glb").name
    record.files["bvh"] = write_bvh_zip(scene, record.folder / f"{stem}-bvh.zip", stem).name
    npz = record.folder / f"{path.stem}.npz"
    if path.suffix.lower() == ".npz":
        shutil.copyfile(path, npz)
    else:
        save_npz_atomic(npz, joints=joints, text=np.array(text), fps=np.array(FPS, np.float32))
    record.files["npz"] = npz.name
    return store.add(record)
