"""The one motion container: N people's motion (generated, or read from a file) and every
file it can be written as.

A :class:`Scene` holds one rigid body per person (:class:`umf.kinematics.Bodies`: bone
lengths, local rotations, a root path) and ``joints``, their forward kinematics: the motion
that every export (NPZ, BVH, GLB, GIF/MP4, SMPL, HumanML3D) writes, so all files of a scene
agree. ``raw_joints`` keeps the positions the body was fitted to (the decoder's output, or
the file's joints) for research; the generator's fit also pins planted feet and keeps
bodies off the floor (:mod:`umf.kinematics`). A scene made from joints alone is fitted on
construction (inverse kinematics once per scene, never per export).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import InitVar, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from umf.kinematics import Bodies, fit_bodies
from umf.skeleton import NUM_JOINTS

__all__ = ["Scene", "slug"]


def slug(text: str, limit: int = 40) -> str:
    """File-name stem from a prompt (what `umf generate` names its files)."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit] or "scene"


@dataclass
class Scene:
    """N people's motion in one frame (metres, Y up).

    Attributes:
        joints: (N, T, 22, 3) float32, the forward kinematics of ``bodies``: what every
            file of the scene holds.
        features: (N, T, 262) de-normalised decoder output (None for motion files).
        text: the prompt (or the file's caption).
        fps: frames per second.
        seed, model: what generated it ("" / None for files).
        meta: free-form (sampling settings, shifts, the floor height, the source file ...).
        raw_joints: (N, T, 22, 3) the decoded positions (after the separation's rigid
            shifts); the bodies were fitted to them once planted feet were anchored
            (:mod:`umf.anchoring`, a floor translation per frame).
        bodies: the rigid skeletons; None only for ``fit=False`` scenes (evaluation),
            whose ``joints`` are then the raw positions and whose exports fit a copy.
    """

    joints: np.ndarray
    features: np.ndarray | None
    text: str
    fps: float
    seed: int | None = None
    model: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    raw_joints: np.ndarray | None = None
    bodies: Bodies | None = None
    fit: InitVar[bool] = True

    def __post_init__(self, fit: bool) -> None:
        joints = np.asarray(self.joints)
        if joints.ndim != 4 or joints.shape[2:] != (NUM_JOINTS, 3):
            raise ValueError(f"a scene's joints are (N, T, 22, 3), got {joints.shape}")
        if self.raw_joints is None:
            self.raw_joints = joints
        if self.bodies is None and fit:
            self.bodies = fit_bodies(self.raw_joints, clean=False)
            joints = self.bodies.joints()
        if (
            self.bodies is not None
            and (self.bodies.num_people, self.bodies.num_frames) != (joints.shape[:2])
        ):
            raise ValueError(
                f"the scene's bodies ({self.bodies.num_people} people, "
                f"{self.bodies.num_frames} frames) do not match its joints {joints.shape}"
            )
        self.joints = joints.astype(np.float32, copy=False)

    # ------------------------------------------------------------------ shape
    @property
    def num_people(self) -> int:
        return int(self.joints.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[1])

    @property
    def seconds(self) -> float:
        return self.num_frames / float(self.fps)

    def rigid(self) -> Scene:
        """This scene, or for a ``fit=False`` scene a fitted copy (what exports write)."""
        if self.bodies is not None:
            return self
        return Scene(self.raw_joints, self.features, self.text, self.fps, self.seed,
                     self.model, dict(self.meta), self.raw_joints)  # fmt: skip

    def frames(self, stop: int, start: int = 0) -> Scene:
        """Frames ``start:stop`` of every array (a copy)."""
        cut = slice(start, stop)

        def part(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[:, cut].copy()

        bodies = None if self.bodies is None else self.bodies.frames(stop, start)
        return Scene(part(self.joints), part(self.features), self.text, self.fps, self.seed,
                     self.model, dict(self.meta), part(self.raw_joints), bodies,
                     fit=self.bodies is not None)  # fmt: skip

    def rotations(self) -> np.ndarray:
        """Local joint rotations (N, T, 22, 3, 3) of the bodies (joint 0: global)."""
        return self.rigid().bodies.rotations  # type: ignore[union-attr]

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path, formats: str | Sequence[str] = ("npz",)) -> list[Path]:
        """Write the scene in every format of ``formats`` (names of :mod:`umf.exports`,
        e.g. ``"npz,bvh,glb"``), all files together or none (:mod:`umf.writer`).

        ``path`` is a directory (files named after the prompt) or a stem such as
        ``out/bow`` (a known suffix like ``.npz`` is dropped): ``out/bow.npz``,
        ``out/bow-p1.bvh`` ... Returns the paths written.
        """
        from umf.exports import check_formats, stem_of
        from umf.writer import write_scene_files

        wanted = check_formats(formats if isinstance(formats, str) else ",".join(formats))
        path = Path(path)
        stem = path / slug(self.text) if path.is_dir() else stem_of(path)
        return write_scene_files(self, stem, wanted)

    def save_npz(self, path: str | Path) -> Path:
        from umf.exports import npz

        return npz.write(self, Path(path))[0]

    def save_bvh(self, path_pattern: str | Path) -> list[Path]:
        """One SMPL-22 BVH per person (metres, shared scene frame); ``{i}`` in the file
        name is replaced by the person number."""
        from umf.exports import bvh

        return bvh.write(self, Path(path_pattern))

    def save_glb(self, path: str | Path) -> Path:
        """The whole scene as one glTF binary: a skinned, animated skeleton per person."""
        from umf.exports import gltf

        return gltf.write(self, Path(path))[0]

    def save_smpl(self, path_pattern: str | Path) -> list[Path]:
        """One SMPL-H / AMASS-style ``.npz`` per person (``{i}``: the person number)."""
        from umf.exports import smpl

        return smpl.write(self, Path(path_pattern))

    def save_humanml3d(self, path_pattern: str | Path) -> list[Path]:
        """One HumanML3D ``.npz`` (263-d vectors, joints, 20 fps) per person."""
        from umf.exports import humanml3d

        return humanml3d.write(self, Path(path_pattern))

    def render(self, path: str | Path, **kwargs: Any) -> Path:
        """A GIF or MP4 of the scene (stick figures, :func:`umf.render.render_animation`)."""
        from umf.render import render_animation

        return render_animation(self.rigid().joints, path, caption=self.text, fps=self.fps,
                                **kwargs)  # fmt: skip
