"""Read a user's motion file as a :class:`umf.scene.Scene`: umf ``.npz`` scenes and ``.bvh``.

What ``umf react --actor`` and ``umf data show`` accept. BVH files may be on our SMPL-22
hierarchy (what ``umf generate --format bvh`` writes) or any skeleton the mocap importer
reads (:mod:`umf.data.skeletons`: Bandai, CMU, Mixamo, SMPL names, or a ``skeleton.json``
beside the file), at any frame rate and in any unit: the one that makes the body an
adult's size (:func:`umf.units.choose_unit`), and the motion is resampled to 30 fps. The
result is the same container as a generated scene (fitted to one rigid body per person,
which leaves a rigid skeleton's joints as they are), so it can be written in any format.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from umf.errors import UMFError
from umf.scene import Scene
from umf.units import check_body_size, choose_unit

FPS = 30.0
MAX_NPZ_JOINTS_BYTES = 256 * 10**6  # 16 people x 10 min at 30 fps is 76 MB
MAX_SECONDS = 600.0  # a motion file longer than 10 min is refused before it is resampled and fitted

Motion = Scene  # what load_motion returned before scenes and motion files were one class


def _load_npz(path: Path) -> tuple[np.ndarray, str, float]:
    try:
        with np.load(path, allow_pickle=False) as z:
            if "joints" not in z:
                raise UMFError(f"{path}: no 'joints' array (expected a umf scene file)")
            size = z.zip.getinfo("joints.npy").file_size  # from the zip directory: not read yet
            if size > MAX_NPZ_JOINTS_BYTES:
                raise UMFError(f"{path}: its joints array unpacks to {size / 1e6:.0f} MB; umf "
                               f"reads at most {MAX_NPZ_JOINTS_BYTES / 1e6:.0f} MB")  # fmt: skip
            joints = np.asarray(z["joints"], dtype=np.float32)
            text = str(z["text"]) if "text" in z else ""
            fps = float(z["fps"]) if "fps" in z else FPS
    except UMFError:
        raise
    except Exception as exc:  # zipfile/pickle/format errors: one line for the user
        raise UMFError(f"{path}: not a readable .npz file ({type(exc).__name__})") from exc
    if joints.ndim == 3:
        joints = joints[None]
    if joints.ndim != 4 or joints.shape[-2:] != (22, 3):
        raise UMFError(f"{path}: joints must be (P, T, 22, 3) or (T, 22, 3), got {joints.shape}")
    return joints, text, fps


def _load_bvh(path: Path) -> tuple[np.ndarray, float]:
    """A BVH on any skeleton :mod:`umf.data.skeletons` recognises (SMPL-named, Bandai, CMU
    cgspeed or Daz, Mixamo), or one a ``skeleton.json`` beside it describes, in metres."""
    from umf.data.mocap import read_motion, to_metres
    from umf.data.skeletons import read_skeleton_json

    mapping = path.parent / "skeleton.json"
    raw = read_motion(path, read_skeleton_json(mapping) if mapping.exists() else None)
    (joints,), _, _ = to_metres([raw])
    return joints[None].astype(np.float32), raw.fps


@dataclass
class MotionFile:
    """A motion file as read and checked, before resampling: ``joints`` (P, T, 22, 3) in
    metres at the file's ``fps``. :meth:`scene` makes the 30 fps scene of a window of it."""

    joints: np.ndarray
    text: str
    fps: float
    meta: dict

    @property
    def num_people(self) -> int:
        return int(self.joints.shape[0])

    @property
    def frames(self) -> int:
        """Its length at 30 fps."""
        from umf.data.bandai import resampled_length

        return resampled_length(self.joints.shape[1], self.fps, FPS)

    def scene(self, first: int = 0, count: int | None = None) -> Scene:
        """Frames ``first`` .. ``first + count`` at 30 fps as a scene, the window cut before
        the resampling and the body fit, so a long file costs what the window costs."""
        from umf.data.bandai import resample

        joints = resample(self.joints, self.fps, FPS, first=first, count=count)
        if joints.shape[1] < 2:
            raise UMFError(f"{self.meta['source']}: no motion from frame {first} on "
                           f"({self.frames} frames at {FPS:g} fps)")  # fmt: skip
        return Scene(np.ascontiguousarray(joints), None, self.text, FPS, meta=dict(self.meta))


def open_motion(path: str | Path) -> MotionFile:
    """Read and check ``path`` (.npz or .bvh): every person, in metres, at its own rate.
    ``meta["source_fps"]`` is the file's frame rate, ``meta["source"]`` its path."""
    path = Path(path)
    if not path.is_file():
        raise UMFError(f"motion file not found: {path}")
    if path.suffix.lower() == ".npz":
        joints, text, fps = _load_npz(path)
    elif path.suffix.lower() == ".bvh":
        (joints, fps), text = _load_bvh(path), ""
    else:
        raise UMFError(f"{path}: unsupported motion file (use .bvh or .npz)")
    if joints.shape[0] == 0 or joints.shape[1] < 2:
        raise UMFError(f"{path}: no motion ({joints.shape[0]} people, {joints.shape[1]} frames)")
    if not np.isfinite(joints).all():
        raise UMFError(f"{path}: the motion contains NaN or infinite values")
    if not 1.0 <= fps <= 1000.0:
        raise UMFError(f"{path}: implausible frame rate {fps:g} fps")
    if (joints.shape[1] - 1) / fps > MAX_SECONDS:
        raise UMFError(f"{path}: {(joints.shape[1] - 1) / fps:.0f} s of motion; umf reads at "
                       f"most {MAX_SECONDS:.0f} s")  # fmt: skip
    meta = {"source_fps": fps, "source": str(path)}
    if path.suffix.lower() == ".npz":  # metres by the format; an adult's size says otherwise
        try:
            unit, name = choose_unit(joints)
        except UMFError as exc:
            raise UMFError(f"{path}: {exc}") from None
        check_body_size(joints, name, str(path))
        if name not in ("m", "stature"):
            joints, meta["converted_from"] = joints * unit, name
    return MotionFile(np.ascontiguousarray(joints, dtype=np.float32), text, fps, meta)


def npz_bodies(path: str | Path, people: int, frames: int):
    """The rigid bodies a umf .npz scene file holds (``offsets``, ``rotations``, ``root``),
    or None when it has none or they do not fit ``people`` x ``frames``."""
    from umf.kinematics import Bodies

    try:
        with np.load(path, allow_pickle=False) as z:
            if not {"offsets", "rotations", "root"} <= set(z.files):
                return None
            parts = [np.asarray(z[k], dtype=np.float64) for k in ("offsets", "rotations", "root")]
        bodies = Bodies(*parts)
    except (ValueError, OSError, KeyError):
        return None
    if (bodies.num_people, bodies.num_frames) != (people, frames):
        return None
    if not all(np.isfinite(a).all() for a in parts):
        return None
    return bodies


def open_scene(path: str | Path, motion: MotionFile | None = None) -> Scene:
    """A scene file as it is, for re-rolling one of its people: a 30 fps umf ``.npz`` keeps
    its joints and its bodies bit for bit; anything else is resampled and fitted once
    (:func:`load_motion`). ``motion``: the file as :func:`open_motion` already read it."""
    motion = open_motion(path) if motion is None else motion
    if motion.fps != FPS or "converted_from" in motion.meta:
        return motion.scene()
    bodies = npz_bodies(path, motion.num_people, motion.joints.shape[1])
    meta = dict(motion.meta)
    own = npz_person_prompts(path, motion.num_people)
    if own is not None:
        meta["person_prompts"] = own
    return Scene(motion.joints, None, motion.text, FPS, meta=meta, bodies=bodies,
                 fit=bodies is None)  # fmt: skip


def npz_person_prompts(path: str | Path, people: int) -> list[str | None] | None:
    """The per-person prompts a umf .npz scene was generated with (one per person, None
    where a person followed the scene prompt alone), or None when it holds none usable."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if "person_prompts" not in z.files:
                return None
            own = json.loads(str(z["person_prompts"]))
    except (ValueError, OSError, KeyError):
        return None
    if not isinstance(own, list) or len(own) != people:
        return None
    if not all(p is None or (isinstance(p, str) and p.strip()) for p in own):
        return None
    return own


def load_motion(path: str | Path) -> Scene:
    """Every person in ``path`` (.npz or .bvh) as a scene in metres at 30 fps
    (:func:`open_motion`, then all of it resampled)."""
    return open_motion(path).scene()
