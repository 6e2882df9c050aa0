"""Skeletons of common mocap libraries, recognised by joint names and mapped to SMPL-22.

A mapping says, for each of the 22 SMPL joints (:data:`umf.skeleton.JOINT_NAMES`), where it
is on the source skeleton: a joint (``"LeftUpLeg"``), the midpoint of two (``["Chest",
"Neck"]``), or a joint's End Site (``"end:lFoot"``). Names are compared after
:func:`normal_name` (case, namespace prefixes such as ``mixamorig:`` and separators dropped),
so ``mixamorig:LeftUpLeg``, ``leftupleg`` and ``Left_Up_Leg`` are one name.

The built-in tables (their joint lists are the documented hierarchies of each library):

================ ===================================================================
``smpl``         SMPL/SMPL-H/SMPL-X joint names (``pelvis``, ``left_hip`` / ``L_Hip``
                 ...), and the SMPL-22 BVH that ``umf generate --format bvh`` writes
``bandai``       Bandai-Namco-Research-Motiondataset (``Hips``, ``UpperLeg_L`` ...)
``cmu-cgspeed``  CMU, cgspeed "MotionBuilder-friendly" conversion (``Hips``,
                 ``LHipJoint``, ``LeftUpLeg``, ``LowerBack``, ``Spine1``, ``Neck1`` ...)
``cmu-daz``      CMU, "Daz-friendly" conversion (``hip``, ``abdomen``, ``chest``,
                 ``lThigh``, ``lShin``, ``lFoot`` ... no toe joint: the foot's End Site)
``mixamo``       Mixamo rigs (``mixamorig:Hips``, ``Spine1``, ``Spine2``, ``LeftToeBase``)
================ ===================================================================

Any other skeleton: a ``skeleton.json`` beside the files, ``{"joints": {our joint: their
joint, ...}}`` with all 22 of our joints, optionally ``"unit"`` (metres per file unit, or
one of ``m``, ``cm``, ``mm``, ``in``, ``cmu``) and ``"fps"`` (overrides the files' frame
time, for conversions that wrote a wrong one).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from umf.errors import UMFError
from umf.skeleton import JOINT_NAMES
from umf.units import UNITS

Source = str | tuple[str, str]  # a joint, "end:<joint>", or the midpoint of two joints


def normal_name(name: str) -> str:
    """Joint name without namespace, case and separators: ``mixamorig:Left_Arm`` -> ``leftarm``."""
    return re.sub(r"[^a-z0-9]", "", name.rsplit(":", 1)[-1].rsplit("|", 1)[-1].lower())


def _table(*sources: Source) -> tuple[Source, ...]:
    if len(sources) != len(JOINT_NAMES):
        raise AssertionError(f"a mapping has 22 entries, got {len(sources)}")
    return sources


# our joint order: pelvis, l_hip, r_hip, spine1, l_knee, r_knee, spine2, l_ankle, r_ankle,
# spine3, l_foot, r_foot, neck, l_collar, r_collar, head, l_shoulder, r_shoulder,
# l_elbow, r_elbow, l_wrist, r_wrist
# fmt: off
SKELETONS: dict[str, tuple[Source, ...]] = {
    "smpl": tuple(JOINT_NAMES),
    "smpl-long": _table(
        "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
        "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
        "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
        "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    ),
    "bandai": _table(
        "Hips", "UpperLeg_L", "UpperLeg_R", "Spine", "LowerLeg_L", "LowerLeg_R", "Chest",
        "Foot_L", "Foot_R", ("Chest", "Neck"), "Toes_L", "Toes_R", "Neck", "Shoulder_L",
        "Shoulder_R", "Head", "UpperArm_L", "UpperArm_R", "LowerArm_L", "LowerArm_R",
        "Hand_L", "Hand_R",
    ),
    # cgspeed's Neck and LeftShoulder start where Spine1 ends: SMPL's neck is their Neck1
    # (just above the shoulders) and each collar the midpoint of Spine1 and the shoulder
    "cmu-cgspeed": _table(
        "Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", ("Spine", "Spine1"),
        "LeftFoot", "RightFoot", "Spine1", "LeftToeBase", "RightToeBase", "Neck1",
        ("Spine1", "LeftArm"), ("Spine1", "RightArm"), "Head", "LeftArm", "RightArm",
        "LeftForeArm", "RightForeArm", "LeftHand", "RightHand",
    ),
    "cmu-daz": _table(
        "hip", "lThigh", "rThigh", "abdomen", "lShin", "rShin", "chest", "lFoot", "rFoot",
        ("chest", "neck"), "end:lFoot", "end:rFoot", "neck", "lCollar", "rCollar", "head",
        "lShldr", "rShldr", "lForeArm", "rForeArm", "lHand", "rHand",
    ),
    "mixamo": _table(
        "Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1",
        "LeftFoot", "RightFoot", "Spine2", "LeftToeBase", "RightToeBase", "Neck",
        "LeftShoulder", "RightShoulder", "Head", "LeftArm", "RightArm", "LeftForeArm",
        "RightForeArm", "LeftHand", "RightHand",
    ),
}
# fmt: on
# SMPL's short capitalised names (L_Hip, R_Knee ...) normalise to the same as "l_hip".
_SPECIFIC_FIRST = ("cmu-cgspeed", "mixamo", "bandai", "cmu-daz", "smpl", "smpl-long")


def _joints_needed(table: Sequence[Source]) -> set[str]:
    out: set[str] = set()
    for s in table:
        names = s if isinstance(s, tuple) else (s.removeprefix("end:"),)
        out.update(normal_name(n) for n in names)
    return out


@dataclass(frozen=True)
class SkeletonMap:
    """How to read SMPL-22 joints off a source skeleton (see the module notes)."""

    name: str
    sources: tuple[Source, ...]
    unit: float | None = None  # metres per file unit; None: guessed from the body's size
    fps: float | None = None  # overrides the file's frame time

    def missing(self, names: Sequence[str]) -> list[str]:
        have = {normal_name(n) for n in names}
        return sorted(n for n in _joints_needed(self.sources) if n not in have)

    def apply(
        self,
        names: Sequence[str],
        positions: np.ndarray,
        rotations: np.ndarray | None = None,
        end_sites: Mapping[int, np.ndarray] | None = None,
    ) -> np.ndarray:
        """(F, J, 3) source positions (+ global rotations for End Sites) -> (F, 22, 3)."""
        index = {normal_name(n): i for i, n in enumerate(names)}

        def at(name: str) -> np.ndarray:
            if name.startswith("end:"):
                j = index[normal_name(name[4:])]
                if rotations is None or not end_sites or j not in end_sites:
                    raise UMFError(f"joint {name[4:]!r} has no End Site")
                return positions[:, j] + rotations[:, j] @ np.asarray(end_sites[j], np.float64)
            return positions[:, index[normal_name(name)]]

        cols = [
            0.5 * (at(s[0]) + at(s[1])) if isinstance(s, tuple) else at(s) for s in self.sources
        ]
        return np.stack(cols, axis=1)


def recognise(names: Sequence[str], label: str = "<motion>") -> SkeletonMap:
    """The built-in skeleton whose joints all appear in ``names``; one-line error if none."""
    have = {normal_name(n) for n in names}
    for key in _SPECIFIC_FIRST:
        if _joints_needed(SKELETONS[key]) <= have:
            return SkeletonMap(key.removesuffix("-long"), SKELETONS[key])
    raise UMFError(
        f"{label}: skeleton of {len(names)} joints (root {names[0] if names else '?'!r}) is none "
        f"of {', '.join(k for k in SKELETONS if k != 'smpl-long')}; describe it in a "
        "skeleton.json (our joint -> your joint)"
    )


def read_skeleton_json(path: Path) -> SkeletonMap:
    """A user's mapping file (module notes); every problem is one line naming the file."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UMFError(f"{path}: not a readable JSON file ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise UMFError(f"{path}: expected a JSON object")
    joints = doc.get("joints")
    unit = _unit(doc.get("unit"), path)
    fps = doc.get("fps")
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, int | float)
                            or not 1 <= fps <= 1000):  # fmt: skip
        raise UMFError(f"{path}: 'fps' must be a number in 1..1000, got {fps!r}")
    if joints is None:
        return SkeletonMap("by-name", (), unit, None if fps is None else float(fps))
    if not isinstance(joints, dict):
        raise UMFError(f"{path}: 'joints' must map our joint names to yours")
    unknown = sorted(set(joints) - set(JOINT_NAMES))
    if unknown:
        raise UMFError(f"{path}: unknown joint(s) {unknown}; ours are {', '.join(JOINT_NAMES)}")
    absent = [n for n in JOINT_NAMES if n not in joints]
    if absent:
        raise UMFError(f"{path}: no entry for {', '.join(absent)} (all 22 are needed)")
    sources: list[Source] = []
    for n in JOINT_NAMES:
        v = joints[n]
        if isinstance(v, str) and v:
            sources.append(v)
        elif isinstance(v, list) and len(v) == 2 and all(isinstance(x, str) and x for x in v):
            sources.append((v[0], v[1]))
        else:
            raise UMFError(f"{path}: {n!r} must be a joint name or a list of two, got {v!r}")
    return SkeletonMap("skeleton.json", tuple(sources), unit, None if fps is None else float(fps))


def _unit(value: object, path: Path) -> float | None:
    if value is None:
        return None
    if isinstance(value, str) and value.lower() in UNITS:
        return UNITS[value.lower()]
    if isinstance(value, int | float) and not isinstance(value, bool) and 0 < value < 1e3:
        return float(value)
    raise UMFError(f"{path}: 'unit' must be metres per unit or one of {', '.join(UNITS)}")
