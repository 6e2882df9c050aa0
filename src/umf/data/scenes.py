"""Multi-person scenes composed from real single-person clips, stored as recipes.

A scene is stored as a *recipe* (clip ids, mirroring, crop, delay, yaw, position), so
the corpus stays small and the joints are rebuilt exactly by :func:`build_scene`. The
relations a recipe can show are in :mod:`umf.data.scene_relations`; the seeded composer
that keeps a scene only when every check of its relation holds (so the caption is true
and nobody walks through anybody else) is :mod:`umf.data.composer`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from umf.data.relations import action_onset
from umf.representation import assemble_features, canonical_transform, mirror_joints, mirror_rot6d

MAX_FRAMES = 300
MIN_FRAMES = 30


@dataclass
class Actor:
    """A single-person clip in its canonical frame, ready to be placed."""

    id: str
    joints: np.ndarray  # (T, 22, 3), first-frame pelvis over the origin, facing +Z
    content: str
    style: str
    onset: int  # frame where the action starts
    rot6d: np.ndarray | None = None  # (T, 21, 6) local rotations, unchanged by placement

    @classmethod
    def from_joints(
        cls, id: str, joints: np.ndarray, content: str, style: str, rot6d: np.ndarray | None = None
    ) -> Actor:
        tf = canonical_transform(torch.from_numpy(np.ascontiguousarray(joints)))
        canon = tf.apply(torch.from_numpy(np.ascontiguousarray(joints))).numpy()
        return cls(id, canon.astype(np.float32), content, style, action_onset(canon), rot6d)


# --------------------------------------------------------------------- geometry
def yaw_rotate(joints: np.ndarray, yaw: float) -> np.ndarray:
    """Rotate about +Y by ``yaw`` (rad): a person facing +Z then faces (sin, 0, cos)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=joints.dtype)
    return joints @ rot.T


def heading_to(src: np.ndarray, dst: np.ndarray) -> float:
    """Yaw that makes someone at ``src`` (x, z) face ``dst`` (x, z)."""
    d = np.asarray(dst, dtype=np.float64) - np.asarray(src, dtype=np.float64)
    return float(np.arctan2(d[0], d[1]))


def place(joints: np.ndarray, yaw: float, xz: Sequence[float]) -> np.ndarray:
    out = yaw_rotate(joints, yaw)
    out[..., 0] += xz[0]
    out[..., 2] += xz[1]
    return out


def time_layout(joints: np.ndarray, delay: int, start: int, length: int) -> np.ndarray:
    """Crop from ``start``, hold the first pose for ``delay`` frames, fit to ``length``."""
    clip = joints[start:]
    if delay > 0:
        clip = np.concatenate([np.repeat(clip[:1], delay, axis=0), clip], axis=0)
    if clip.shape[0] < length:  # hold the last pose
        pad = np.repeat(clip[-1:], length - clip.shape[0], axis=0)
        clip = np.concatenate([clip, pad], axis=0)
    return clip[:length]


def build_scene(recipe: dict[str, Any], actors: dict[str, Actor]) -> np.ndarray:
    """Joints (P, T, 22, 3) of a scene recipe, exactly as the composer made it."""
    people = []
    for p in recipe["people"]:
        j = actors[p["clip"]].joints
        if p.get("mirrored", False):
            j = mirror_joints_np(j)
        j = time_layout(j, p["delay"], p["start"], recipe["num_frames"])
        people.append(place(j, p["yaw"], p["xz"]))
    return np.stack(people).astype(np.float32)


def build_scene_features(recipe: dict[str, Any], actors: dict[str, Actor]) -> np.ndarray:
    """Features (P, T - 1, 262) of a scene recipe; needs actors with ``rot6d``."""
    joints, rot = build_scene(recipe, actors), scene_rotations(recipe, actors)
    return scene_features_of(joints, rot)


def scene_rotations(recipe: dict[str, Any], actors: dict[str, Actor]) -> np.ndarray:
    """Local 6-D rotations (P, T, 21, 6) of a scene recipe's people, laid out in time as
    :func:`build_scene` lays out their joints; needs actors with ``rot6d``."""
    out = []
    for person in recipe["people"]:
        rot = actors[person["clip"]].rot6d
        if rot is None:
            raise ValueError(f"actor {person['clip']} has no rotations")
        if person.get("mirrored", False):
            rot = mirror_rot6d(torch.from_numpy(rot)).numpy()
        out.append(time_layout(rot, person["delay"], person["start"], recipe["num_frames"]))
    return np.stack(out)


def scene_features_of(joints: np.ndarray, rot6d: np.ndarray) -> np.ndarray:
    """Features (P, T - 1, 262) of people's joints (P, T, 22, 3) and rotations (P, T, 21, 6)."""
    return torch.stack([
        assemble_features(torch.from_numpy(np.ascontiguousarray(j)),
                          torch.from_numpy(np.ascontiguousarray(r)))
        for j, r in zip(joints, rot6d, strict=True)
    ]).numpy()  # fmt: skip


def mirror_joints_np(joints: np.ndarray) -> np.ndarray:
    return mirror_joints(torch.from_numpy(np.ascontiguousarray(joints))).numpy()


def forward_travel(joints: np.ndarray) -> np.ndarray:
    """Distance travelled along the first-frame heading (+Z for canonical clips), (T,)."""
    return joints[:, 0, 2] - joints[0, 0, 2]


# --------------------------------------------------------------------- relations
