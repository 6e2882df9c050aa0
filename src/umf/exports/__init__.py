"""Every file format a scene is written in, behind one small interface.

Each format is a module here with ``write(scene, path) -> list[Path]``: ``path`` is the
file (``out/bow.glb``) or, for formats with one file per person, a pattern whose ``{i}``
is the person number (``out/bow-p{i}.bvh``). Writers read ``scene.joints`` /
``scene.bodies`` (the one fitted motion, :mod:`umf.scene`), so every file agrees. Making a
scene's files appear together (or not at all) is :mod:`umf.writer`'s job; ``Scene.save``
and the CLI go through it.

This module imports no writer, so the CLI can check a ``--format`` list cheaply.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from umf.errors import UMFError

__all__ = ["FORMATS", "Format", "stem_of", "targets", "write_formats"]


@dataclass(frozen=True)
class Format:
    """One file format: its name (``--format``), file suffix and writer module."""

    name: str
    suffix: str
    per_person: bool
    module: str
    summary: str

    def path(self, stem: Path) -> Path:
        """What ``write`` is given: the file, or the per-person pattern."""
        tail = "-p{i}" if self.per_person else ""
        return stem.parent / f"{stem.name}{tail}{self.suffix}"

    def targets(self, stem: Path, num_people: int) -> list[Path]:
        if not self.per_person:
            return [self.path(stem)]
        return [stem.parent / f"{stem.name}-p{i}{self.suffix}" for i in range(1, num_people + 1)]

    def write(self, scene: Any, stem: Path) -> list[Path]:
        return importlib.import_module(self.module).write(scene, self.path(stem))


FORMATS: dict[str, Format] = {
    f.name: f
    for f in (
        Format("npz", ".npz", False, "umf.exports.npz", "joints, raw joints, bodies, features"),
        Format("bvh", ".bvh", True, "umf.exports.bvh", "SMPL-22 skeleton per person"),
        Format("glb", ".glb", False, "umf.exports.gltf", "skinned, animated glTF scene"),
        Format("gif", ".gif", False, "umf.exports.video", "stick-figure animation"),
        Format("mp4", ".mp4", False, "umf.exports.video", "stick-figure video"),
        Format("smpl", ".smpl.npz", True, "umf.exports.smpl", "SMPL-H/AMASS poses per person"),
        Format("humanml3d", ".humanml3d.npz", True, "umf.exports.humanml3d", "HumanML3D vectors"),
    )
}


def stem_of(path: Path) -> Path:
    """``out/bow.npz`` -> ``out/bow``: a path with a format's suffix loses it."""
    for f in sorted(FORMATS.values(), key=lambda f: -len(f.suffix)):
        if path.name.endswith(f.suffix) and len(path.name) > len(f.suffix):
            return path.parent / path.name[: -len(f.suffix)]
    return path


def targets(stem: Path, wanted: Sequence[str], num_people: int) -> list[Path]:
    """Every path the formats ``wanted`` write for a scene of ``num_people`` at ``stem``."""
    return [p for n in FORMATS if n in wanted for p in FORMATS[n].targets(stem, num_people)]


def write_formats(scene: Any, stem: Path, wanted: Sequence[str]) -> list[Path]:
    """Write ``scene`` in every format of ``wanted`` (registry order); returns the paths."""
    scene = scene.rigid()
    return [p for name in FORMATS if name in wanted for p in FORMATS[name].write(scene, stem)]


def __getattr__(name: str) -> Any:  # ``from umf.exports import write_glb`` (older API)
    if name in ("scene_to_gltf", "write_glb"):
        from umf.exports import gltf

        return getattr(gltf, name)
    raise AttributeError(name)


def check_formats(formats: str) -> list[str]:
    """Names in ``"npz,bvh"`` form, checked against :data:`FORMATS`, each once, in order."""
    wanted = [f.strip().lower() for f in formats.split(",") if f.strip()]
    bad = [f for f in wanted if f not in FORMATS]
    if bad or not wanted:
        raise UMFError(f"unknown format {','.join(bad) or formats!r}; choose from "
                       f"{tuple(FORMATS)}")  # fmt: skip
    return list(dict.fromkeys(wanted))
