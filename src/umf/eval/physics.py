"""Physical plausibility of motion: inter-person penetration, foot skating, floating,
ground penetration and jitter.

Everything takes SMPL-22 joints in metres, Y up, the floor at y = 0, sampled at ``fps``
(scenes are (N, T, 22, 3), single people (T, 22, 3)) and returns plain floats. None of
these needs a learned evaluator, so they apply equally to real and generated motion and
to every person index of the per-person study (:mod:`umf.eval.accumulation`).

Real data sets the reference. Composed Bandai test scenes of the full corpus (300 pairs,
200 groups of 3-6; person means): capsule penetration 0 (the composer keeps people
> 25 cm apart), skate ratio 0.053 / 0.043 (0 for standing gestures, about 0.08 walking,
0.13 running), grounded foot speed 0.12 / 0.11 m/s, floating ratio 0.024 / 0.016
(running flight phases), no joint under the floor, acceleration 5.0 / 4.0 m/s^2, jerk
108 / 87 m/s^3.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from umf.capsules import (  # noqa: F401  (re-exported: the metrics are read from here)
    _BONE_CHILDREN,
    _BONE_PARENTS,
    BONE_RADII,
    as_numpy,
    bone_radii,
    capsule_penetration,
    segment_distance,
)
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT, NUM_JOINTS

PENETRATION_THRESHOLD = 0.01  # m: deeper overlaps count as a penetrating frame

# --------------------------------------------------------------------- foot / floor
FOOT_JOINTS = (*FOOT_LEFT, *FOOT_RIGHT)  # l_ankle, l_foot (toes), r_ankle, r_foot
# A foot is planted when its ankle and its toe joint are both below these heights (ankle,
# toe). The Bandai ankle sits 7.5 cm above the floor when the foot is flat and the toe
# joint on it; the toe threshold equals FLOAT_HEIGHT, so a foot below it either stands or
# floats. (InterGen's contact rule uses 12 cm / 5 cm.)
GROUND_HEIGHTS = (0.10, 0.05)
SKATE_SPEED = 0.5  # m/s: a planted foot moving faster than this is skating
FLOAT_HEIGHT = 0.05  # m: the lowest foot joint above this means the person floats
GROUND_PENETRATION_THRESHOLD = 0.01  # m: a joint deeper below the floor counts


def penetration_matrix(joints: Any) -> np.ndarray:
    """Pairwise capsule penetration depth (N, N, T) in metres; symmetric, zero diagonal."""
    joints = as_numpy(joints)
    n, t = joints.shape[:2]
    out = np.zeros((n, n, t))
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = out[j, i] = capsule_penetration(joints[i], joints[j])
    return out


def _depth_summary(depth: np.ndarray, threshold: float) -> dict[str, float]:
    """Mean (cm), fraction above ``threshold`` and max (cm) of per-frame depths."""
    if depth.size == 0:
        return {"penetration_cm": 0.0, "penetration_frac": 0.0, "penetration_max_cm": 0.0}
    return {
        "penetration_cm": float(depth.mean() * 100),
        "penetration_frac": float((depth > threshold).mean()),
        "penetration_max_cm": float(depth.max() * 100),
    }


def interpenetration(
    joints: Any, threshold: float = PENETRATION_THRESHOLD, matrix: np.ndarray | None = None
) -> list[dict[str, float]]:
    """Per person: penetration of the body capsules with anybody else.

    For person k and frame t the depth is max over other people j of
    ``penetration_matrix[k, j, t]``. ``penetration_cm`` is its mean over frames (cm),
    ``penetration_frac`` the fraction of frames deeper than ``threshold`` (1 cm),
    ``penetration_max_cm`` the deepest overlap. One person alone scores 0.
    """
    m = penetration_matrix(joints) if matrix is None else matrix
    n = m.shape[0]
    if n < 2:
        return [_depth_summary(np.zeros(0), threshold) for _ in range(n)]
    return [_depth_summary(m[k].max(0), threshold) for k in range(n)]


def penetration_with_previous(
    joints: Any, threshold: float = PENETRATION_THRESHOLD, matrix: np.ndarray | None = None
) -> list[dict[str, float]]:
    """Like :func:`interpenetration`, but person k only against persons 1..k-1.

    The S-Flow adds people one at a time, each reacting to those before it; this is
    the penetration each new person is responsible for. Person 1 scores 0.
    """
    m = penetration_matrix(joints) if matrix is None else matrix
    out = [_depth_summary(np.zeros(0), threshold)]
    out += [_depth_summary(m[k, :k].max(0), threshold) for k in range(1, m.shape[0])]
    return out


# --------------------------------------------------------------------- feet and floor
def foot_skating(
    joints: Any,
    fps: float,
    heights: tuple[float, float] = GROUND_HEIGHTS,
    speed: float = SKATE_SPEED,
) -> dict[str, float]:
    """Foot skating of one person (T, 22, 3).

    For each foot and each step t -> t+1, the foot is *planted* when its ankle and its
    toe joint are both below their thresholds (``heights``: ankle, toe) at both ends of
    the step; its speed is the *smaller* horizontal (XZ) speed of the two joints (a
    planted foot may pivot about its heel or its toes, but one of them stays put); it
    *skates* when planted yet faster than ``speed`` (m/s). Judged per joint instead,
    heel strikes and toe-offs of real walking count as skating (12 % of the real test
    scenes' foot steps rather than 5 %); what remains on real data is mostly the swing
    phase of shuffling gaits, whose toes pass within 2 cm of the floor. Returns ``skate_ratio``
    (skating / planted foot-steps), ``skate_speed`` (mean speed of the skating
    foot-steps, m/s), ``grounded_speed`` (mean speed of all planted foot-steps, m/s: a
    threshold-free sliding measure) and ``grounded_frac`` (planted / all foot-steps).
    All are 0 when no foot is ever planted.
    """
    j = as_numpy(joints)
    feet = j[:, [list(FOOT_LEFT), list(FOOT_RIGHT)]]  # (T, 2 feet, ankle / toe, 3)
    thr = np.array(heights)
    planted = (np.maximum(feet[1:, ..., 1], feet[:-1, ..., 1]) < thr).all(-1)  # (T-1, 2)
    v = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1).min(-1) * fps
    skating = planted & (v > speed)
    n_ground, n_skate = int(planted.sum()), int(skating.sum())
    return {
        "skate_ratio": n_skate / n_ground if n_ground else 0.0,
        "skate_speed": float(v[skating].mean()) if n_skate else 0.0,
        "grounded_speed": float(v[planted].mean()) if n_ground else 0.0,
        "grounded_frac": n_ground / planted.size if planted.size else 0.0,
    }


def floating(joints: Any, threshold: float = FLOAT_HEIGHT) -> dict[str, float]:
    """Floating of one person (T, 22, 3): the lowest foot joint above the floor.

    ``float_ratio``: fraction of frames whose lowest foot joint (ankles, toes) is higher
    than ``threshold`` (5 cm; real jumps and running flight phases count too).
    ``float_height_cm``: mean over frames of that lowest height, clipped at 0 (cm).
    """
    low = as_numpy(joints)[:, list(FOOT_JOINTS), 1].min(-1)
    return {
        "float_ratio": float((low > threshold).mean()),
        "float_height_cm": float(np.clip(low, 0.0, None).mean() * 100),
    }


def ground_penetration(
    joints: Any, threshold: float = GROUND_PENETRATION_THRESHOLD
) -> dict[str, float]:
    """Ground penetration of one person (T, 22, 3): joints below the floor y = 0.

    Per frame the depth is max(0, -lowest joint height). ``ground_pen_cm``: its mean over
    frames (cm); ``ground_pen_ratio``: fraction of frames deeper than ``threshold``
    (1 cm); ``ground_pen_max_cm``: the deepest.
    """
    depth = np.clip(-as_numpy(joints)[..., 1].min(-1), 0.0, None)
    return {
        "ground_pen_cm": float(depth.mean() * 100),
        "ground_pen_ratio": float((depth > threshold).mean()),
        "ground_pen_max_cm": float(depth.max() * 100),
    }


def jitter(joints: Any, fps: float) -> dict[str, float]:
    """Jitter of one person (T, 22, 3) from finite differences of all 22 joints.

    ``accel``: mean acceleration magnitude (m/s^2, second difference x fps^2);
    ``jerk``: mean jerk magnitude (m/s^3, third difference x fps^3). Means run over
    joints and frames; too short clips give NaN.
    """
    j = as_numpy(joints)
    out = {"accel": float("nan"), "jerk": float("nan")}
    if j.shape[0] >= 3:
        out["accel"] = float(np.linalg.norm(np.diff(j, 2, axis=0), axis=-1).mean() * fps**2)
    if j.shape[0] >= 4:
        out["jerk"] = float(np.linalg.norm(np.diff(j, 3, axis=0), axis=-1).mean() * fps**3)
    return out


# --------------------------------------------------------------------- reports
def person_physics(joints: Any, fps: float) -> dict[str, float]:
    """All single-person measures of one person (T, 22, 3)."""
    return {
        **foot_skating(joints, fps),
        **floating(joints),
        **ground_penetration(joints),
        **jitter(joints, fps),
    }


def physics_report(joints: Any, fps: float = 30.0) -> dict[str, Any]:
    """Every physics measure of a scene (N, T, 22, 3).

    Top-level floats are means over the N people of the per-person values (penetration:
    each person against everybody else, so scenes of any size compare);
    ``penetration_max_cm`` is the scene's deepest overlap. ``per_person`` holds one dict
    of floats per person, in scene order.
    """
    j = as_numpy(joints)
    if j.ndim != 4 or j.shape[-2:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected joints (N, T, 22, 3), got {j.shape}")
    per_person = [
        {**pen, **person_physics(p, fps)} for pen, p in zip(interpenetration(j), j, strict=True)
    ]
    report: dict[str, Any] = average_reports(per_person)
    report["penetration_max_cm"] = max(p["penetration_max_cm"] for p in per_person)
    report["per_person"] = per_person
    return report


def average_reports(reports: Iterable[Mapping[str, Any]]) -> dict[str, float]:
    """Mean of every float entry over reports (NaNs ignored); other entries are dropped."""
    reports = list(reports)
    keys: Sequence[str] = (
        [k for k, v in reports[0].items() if isinstance(v, float | int)] if reports else []
    )
    out = {}
    for k in keys:
        vals = np.array([r[k] for r in reports if k in r], dtype=np.float64)
        out[k] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    return out
