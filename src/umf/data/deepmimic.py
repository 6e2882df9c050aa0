"""DeepMimic reference motions (JSON ``*.txt`` with ``"Frames"``) -> SMPL-22 joints.

Format (xbpeng/DeepMimic): each row of ``"Frames"`` is ``[frame duration (s), root position
(3), root rotation (4), chest (4), neck (4), right hip (4), right knee (1), right ankle (4),
right shoulder (4), right elbow (1), left hip (4), left knee (1), left ankle (4), left
shoulder (4), left elbow (1)]``: metres, Y up, quaternions (w, x, y, z); knees and elbows are
one angle about their local z axis. The root's rotation is global, the others local, and a
joint sits at its parent's position plus the parent's rotation of its attachment offset.

The humanoid has 15 joints; SMPL-22's others are placed on it (documented in
:data:`PLACED`): spine1 between root and chest, spine3 a quarter of the way from chest to
neck, collars 40 % of the way from the neck to each shoulder, the head 10 cm up the neck's
axis, each toe 12 cm forward and 4.5 cm down in its ankle's frame (the foot box of the
character file reaches 13 cm forward and 5 cm down).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from umf.errors import UMFError

# The humanoid3d character (joint, parent, attachment offset in metres, degrees of freedom).
HUMANOID3D: tuple[tuple[str, int, tuple[float, float, float], int], ...] = (
    ("root", -1, (0.0, 0.0, 0.0), 7),
    ("chest", 0, (0.0, 0.236151, 0.0), 4),
    ("neck", 1, (0.0, 0.223894, 0.0), 4),
    ("right_hip", 0, (0.0, 0.0, 0.084887), 4),
    ("right_knee", 3, (0.0, -0.421546, 0.0), 1),
    ("right_ankle", 4, (0.0, -0.40987, 0.0), 4),
    ("right_shoulder", 1, (-0.02405, 0.2435, 0.18311), 4),
    ("right_elbow", 6, (0.0, -0.274788, 0.0), 1),
    ("right_wrist", 7, (0.0, -0.258947, 0.0), 0),
    ("left_hip", 0, (0.0, 0.0, -0.084887), 4),
    ("left_knee", 9, (0.0, -0.421546, 0.0), 1),
    ("left_ankle", 10, (0.0, -0.40987, 0.0), 4),
    ("left_shoulder", 1, (-0.02405, 0.2435, -0.18311), 4),
    ("left_elbow", 12, (0.0, -0.274788, 0.0), 1),
    ("left_wrist", 13, (0.0, -0.258947, 0.0), 0),
)
FRAME_WIDTH = 1 + sum(d for *_, d in HUMANOID3D)  # 44 numbers a row
HEAD_UP = 0.10
TOE = (0.12, -0.045, 0.0)
PLACED = {
    "spine1": "45 % of the way from root to chest",
    "spine3": "25 % of the way from chest to neck",
    "collars": "40 % of the way from neck to shoulder",
    "head": f"{HEAD_UP} m up the neck's y axis",
    "toes": f"{TOE[:2]} m (forward, up) in the ankle's frame",
}


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), normalised here -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not (n > 1e-8).all():
        raise UMFError("a zero quaternion in the motion")
    w, x, y, z = np.moveaxis(q / n, -1, 0)
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape(*q.shape[:-1], 3, 3)  # fmt: skip


def _about_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros((*angle.shape, 3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1], m[..., 2, 2] = c, -s, s, c, 1.0
    return m


def forward_kinematics(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, 44) DeepMimic rows -> global positions (F, 15, 3) and rotations (F, 15, 3, 3)."""
    f = frames.shape[0]
    pos = np.zeros((f, len(HUMANOID3D), 3))
    rot = np.zeros((f, len(HUMANOID3D), 3, 3))
    col = 1
    for j, (_, parent, offset, dof) in enumerate(HUMANOID3D):
        if dof == 7:
            local_t, local_r = (
                frames[:, col : col + 3],
                quat_to_matrix(frames[:, col + 3 : col + 7]),
            )
        else:
            local_t = np.broadcast_to(np.asarray(offset), (f, 3))
            if dof == 4:
                local_r = quat_to_matrix(frames[:, col : col + 4])
            elif dof == 1:
                local_r = _about_z(frames[:, col])
            else:
                local_r = np.broadcast_to(np.eye(3), (f, 3, 3))
        col += dof
        if parent < 0:
            pos[:, j], rot[:, j] = local_t, local_r
        else:
            rot[:, j] = rot[:, parent] @ local_r
            pos[:, j] = pos[:, parent] + (rot[:, parent] @ local_t[..., None])[..., 0]
    return pos, rot


def to_smpl22(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Humanoid3d joints (F, 15, 3) + rotations -> SMPL-22 (F, 22, 3), module notes."""
    idx = {name: i for i, (name, *_) in enumerate(HUMANOID3D)}
    p = {n: pos[:, i] for n, i in idx.items()}
    lerp = lambda a, b, t: a + t * (b - a)  # noqa: E731

    def local(joint: str, v) -> np.ndarray:
        return p[joint] + rot[:, idx[joint]] @ np.asarray(v, np.float64)

    cols = [
        p["root"], p["left_hip"], p["right_hip"], lerp(p["root"], p["chest"], 0.45),
        p["left_knee"], p["right_knee"], p["chest"], p["left_ankle"], p["right_ankle"],
        lerp(p["chest"], p["neck"], 0.25), local("left_ankle", TOE), local("right_ankle", TOE),
        p["neck"], lerp(p["neck"], p["left_shoulder"], 0.4),
        lerp(p["neck"], p["right_shoulder"], 0.4), local("neck", (0.0, HEAD_UP, 0.0)),
        p["left_shoulder"], p["right_shoulder"], p["left_elbow"], p["right_elbow"],
        p["left_wrist"], p["right_wrist"],
    ]  # fmt: skip
    return np.stack(cols, axis=1)


def is_deepmimic(text: str) -> bool:
    """A JSON document with a ``"Frames"`` list (cheap check before parsing)."""
    return '"Frames"' in text


def read_deepmimic(path: Path, text: str | None = None) -> tuple[np.ndarray, float, bool]:
    """SMPL-22 joints (F, 22, 3) in metres, the frame rate, and whether the clip loops."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8") if text is None else text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UMFError(
            f"{path}: not a readable DeepMimic JSON file ({type(exc).__name__})"
        ) from None
    rows = doc.get("Frames") if isinstance(doc, dict) else None
    if not isinstance(rows, list) or not rows:
        raise UMFError(f"{path}: no 'Frames' list")
    try:
        frames = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise UMFError(f"{path}: 'Frames' rows are not lists of numbers of one length") from None
    if frames.ndim != 2 or frames.shape[1] != FRAME_WIDTH:
        raise UMFError(f"{path}: each frame must have {FRAME_WIDTH} numbers (the humanoid3d "
                       f"character), got shape {frames.shape}")  # fmt: skip
    if not np.isfinite(frames).all():
        raise UMFError(f"{path}: non-finite values in 'Frames'")
    dt = float(np.median(frames[:, 0]))
    if not 1e-3 <= dt <= 1.0:
        raise UMFError(f"{path}: implausible frame duration {dt:g} s")
    pos, rot = forward_kinematics(frames)
    return to_smpl22(pos, rot), 1.0 / dt, doc.get("Loop") == "wrap"
