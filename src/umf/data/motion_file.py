"""Read a user's motion file as a :class:`umf.scene.Scene`: umf ``.npz`` scenes and ``.bvh``.

What ``umf react --actor`` and ``umf data show`` accept. BVH files may be on our SMPL-22
hierarchy (what ``umf generate --format bvh`` writes) or on the Bandai skeleton, at any
frame rate and in metres, centimetres, millimetres or inches: the unit is the one that
makes the body about as tall as a person, and the motion is resampled to 30 fps. The
result is the same container as a generated scene (fitted to one rigid body per person,
which leaves a rigid skeleton's joints as they are), so it can be written in any format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from umf.errors import UMFError
from umf.scene import Scene

FPS = 30.0
# Candidate units of a BVH file, in metres per unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
PERSON_HEIGHT = 1.5  # metres: head-to-toe joint span of an adult, what a unit guess aims for


Motion = Scene  # what load_motion returned before scenes and motion files were one class


def guess_unit(joints: np.ndarray) -> float:
    """Metres per file unit: the candidate that brings the first pose's height (any axis
    span of a standing body is dominated by its height) closest to a person's, in log
    scale so a child in metres and a giant in centimetres are still told apart."""
    first = joints[..., 0, :, :].reshape(-1, 22, 3)
    span = float(np.ptp(first, axis=1).max())
    if not np.isfinite(span) or span <= 0:
        raise UMFError("the motion has no extent (all joints at one point)")
    return min(UNITS.values(), key=lambda u: abs(np.log(span * u / PERSON_HEIGHT)))


def _load_npz(path: Path) -> tuple[np.ndarray, str, float]:
    try:
        with np.load(path, allow_pickle=False) as z:
            if "joints" not in z:
                raise UMFError(f"{path}: no 'joints' array (expected a umf scene file)")
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
    from umf.data.bandai import retarget_to_smpl22
    from umf.data.bvh import forward_kinematics, read_bvh
    from umf.skeleton import JOINT_NAMES

    bvh = read_bvh(path)
    if not bvh.frame_time > 0:
        raise UMFError(f"{path}: 'Frame Time: {bvh.frame_time:g}' (must be positive seconds)")
    pos, _ = forward_kinematics(bvh)
    pos = np.asarray(pos, dtype=np.float64)
    index = {n: i for i, n in enumerate(bvh.names)}
    if all(n in index for n in JOINT_NAMES):  # SMPL-22 by name, whatever the file's order
        joints = pos[:, [index[n] for n in JOINT_NAMES]]
    else:
        try:  # the Bandai skeleton; retarget_to_smpl22 also turns cm into m, undo that
            joints = retarget_to_smpl22(pos, bvh.names).astype(np.float64) * 100.0
        except KeyError as exc:
            raise UMFError(
                f"{path}: skeleton of {pos.shape[1]} joints is neither SMPL-22 nor Bandai"
            ) from exc
    joints = joints * guess_unit(joints)
    return joints[None].astype(np.float32), 1.0 / bvh.frame_time


def load_motion(path: str | Path) -> Scene:
    """Every person in ``path`` (.npz or .bvh) as a scene in metres at 30 fps;
    ``meta["source_fps"]`` is the file's frame rate, ``meta["source"]`` its path."""
    from umf.data.bandai import resample

    path = Path(path)
    if not path.is_file():
        raise UMFError(f"motion file not found: {path}")
    if path.suffix.lower() == ".npz":
        joints, text, fps = _load_npz(path)
    elif path.suffix.lower() == ".bvh":
        (joints, fps), text = _load_bvh(path), ""
    else:
        raise UMFError(f"{path}: unsupported motion file (use .bvh or .npz)")
    if not np.isfinite(joints).all():
        raise UMFError(f"{path}: the motion contains NaN or infinite values")
    if not 1.0 <= fps <= 1000.0:
        raise UMFError(f"{path}: implausible frame rate {fps:g} fps")
    joints = resample(np.ascontiguousarray(joints, dtype=np.float32), fps, FPS)
    return Scene(joints, None, text, FPS, meta={"source_fps": fps, "source": str(path)})
