"""NPZ: the scene as numpy arrays, read back by :func:`umf.data.motion_file.load_motion`.

Keys: ``joints`` (N, T, 22, 3) the motion every other file holds, ``raw_joints`` the
positions it was fitted to (decoder output), the rigid bodies ``offsets`` (N, 22, 3),
``rotations`` (N, T, 22, 3, 3) local rotations and ``root`` (N, T, 3), ``features``
(N, T, 262) when the scene was generated, ``text``, ``fps``, ``seed`` (-1: none),
``model_version`` and ``umf_version``, and ``coverage`` (JSON: how well the prompt is
covered by what the model was trained on, :mod:`umf.coverage`) when the model says;
``person_prompts`` and ``person_coverage`` (JSON lists, one entry per person, null for a
person who followed the scene prompt alone) when the scene was generated with them. Metres,
Y up, float32.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from umf.io import save_npz_atomic
from umf.version import __version__

__all__ = ["scene_arrays", "write"]


def scene_arrays(scene: Any) -> dict[str, np.ndarray]:
    """Every array the NPZ of ``scene`` holds."""
    bodies = scene.rigid().bodies
    arrays = {
        "joints": scene.joints.astype(np.float32),
        "raw_joints": np.asarray(scene.raw_joints, dtype=np.float32),
        "offsets": bodies.offsets.astype(np.float32),
        "rotations": bodies.rotations.astype(np.float32),
        "root": bodies.root.astype(np.float32),
        "text": np.array(scene.text),
        "fps": np.array(scene.fps, dtype=np.float32),
        "seed": np.array(-1 if scene.seed is None else scene.seed),
        "model_version": np.array(scene.model),
        "umf_version": np.array(__version__),
    }
    if scene.features is not None:
        arrays["features"] = np.asarray(scene.features, dtype=np.float32)
    if isinstance(scene.meta.get("coverage"), dict):
        arrays["coverage"] = np.array(json.dumps(scene.meta["coverage"]))
    for key in ("person_prompts", "person_coverage"):
        if isinstance(scene.meta.get(key), list):
            arrays[key] = np.array(json.dumps(scene.meta[key]))
    if isinstance(scene.meta.get("take"), dict):  # the real take a couple was finished from
        arrays["take"] = np.array(json.dumps(scene.meta["take"]))
    return arrays


def write(scene: Any, path: Path) -> list[Path]:
    """One ``.npz`` of the whole scene, written atomically."""
    save_npz_atomic(path, **scene_arrays(scene))
    return [Path(path)]
