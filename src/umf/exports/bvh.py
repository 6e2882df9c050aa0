"""BVH: one file per person, the SMPL-22 hierarchy of :mod:`umf.skeleton`.

Offsets are the person's fitted bone offsets (T-pose, facing +Z), the root has position
and ZXY rotation channels, every other joint ZXY rotations; metres, the shared scene
frame. The rotations are the scene's bodies, so forward kinematics of the file is
``scene.joints`` (to the 6 decimals written).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from umf.bvh import write_smpl22_bvh

__all__ = ["person_path", "write"]


def person_path(pattern: Path, i: int) -> Path:
    """``{i}`` in the file name (not str.format: directories may hold braces) -> ``i``."""
    return pattern.parent / pattern.name.replace("{i}", str(i))


def write(scene: Any, pattern: Path) -> list[Path]:
    """One BVH per person; ``{i}`` in the file name is the person number (1-based)."""
    bodies = scene.rigid().bodies
    out = []
    for i in range(bodies.num_people):
        path = person_path(Path(pattern), i + 1)
        write_smpl22_bvh(path, bodies.rotations[i], bodies.root[i], bodies.offsets[i], scene.fps)
        out.append(path)
    return out
