"""HumanML3D: each person's 263-d vectors and joints at 20 fps, what text-to-motion
evaluators (T2M, and the metrics built on it) read.

One ``.npz`` per person:

- ``new_joint_vecs`` (T - 1, 263): the vectors, :func:`umf.humanml3d.encode_joints`
  (layout and conventions there), heading smoothed as HumanML3D's processing does;
- ``new_joints`` (T, 22, 3): the joints in HumanML3D's canonical frame (first frame's root
  above the origin facing +Z, the floor at y = 0); ``recover_joints(new_joint_vecs)`` gives
  its first T - 1 frames back;
- ``text`` (the prompt) and ``fps`` (20).

Saving ``new_joint_vecs`` as ``new_joint_vecs/<id>.npy`` (and the text as
``texts/<id>.txt``) makes a HumanML3D-layout folder. Two differences to the released data
remain: the bodies keep their own bone lengths (HumanML3D retargets every clip to one
skeleton first), and the 6-D rotations are umf's inverse kinematics, not HumanML3D's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from umf.humanml3d import HUMANML3D_FPS, canonicalize_first_frame, encode_joints, resample
from umf.io import save_npz_atomic

__all__ = ["HEADING_SIGMA", "person_arrays", "write"]

HEADING_SIGMA = 20.0  # frames: HumanML3D's smoothing of the facing direction


def person_arrays(joints: np.ndarray, fps: float, floor: float | None) -> dict[str, np.ndarray]:
    """One person's joints (T, 22, 3) at ``fps`` -> ``new_joint_vecs`` and ``new_joints``.

    ``floor`` is the height put at y = 0 (None: the person's lowest joint, as HumanML3D).
    """
    j = torch.from_numpy(np.asarray(joints, dtype=np.float64))
    j = resample(j, float(fps), HUMANML3D_FPS)
    if j.shape[0] < 2:
        raise ValueError("HumanML3D export needs at least 2 frames at 20 fps")
    j[..., 1] -= float(j[..., 1].min()) if floor is None else floor
    vecs = encode_joints(j, heading_sigma=HEADING_SIGMA)
    canon = canonicalize_first_frame(j, HEADING_SIGMA)
    return {
        "new_joint_vecs": vecs.numpy().astype(np.float32),
        "new_joints": canon.numpy().astype(np.float32),
        "fps": np.array(HUMANML3D_FPS, dtype=np.float32),
    }


def write(scene: Any, pattern: Path) -> list[Path]:
    """One HumanML3D ``.npz`` per person; ``{i}`` in the file name is the person number."""
    from umf.exports.bvh import person_path

    floor = scene.meta.get("floor")
    out = []
    for i, person in enumerate(scene.joints):
        path = person_path(Path(pattern), i + 1)
        arrays = person_arrays(person, scene.fps, floor)
        save_npz_atomic(path, text=np.array(scene.text), **arrays)
        out.append(path)
    return out
