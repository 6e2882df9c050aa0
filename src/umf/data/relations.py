"""Machine-readable relations between people in a scene, and their checks.

A scene's relation record lists constraints such as "person 0 faces person 1 at the
start" or "person 1 is on person 0's left". The scene composer only keeps scenes whose
own record checks true; the evaluation later runs the same checks on generated scenes.

All checks take joints (P, T, 22, 3) in metres, Y up, and return a
:class:`CheckResult` with the measured value, so reports can show *how* wrong a scene is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from umf.skeleton import FACE_JOINTS

FACING_TOLERANCE_DEG = 45.0
SAME_HEADING_TOLERANCE_DEG = 35.0
CONTACT_DISTANCE = 0.25  # m between any two joints of different people: closer counts as contact
SIDE_MARGIN = 0.2  # m to one side of a person under which another stands on neither side


@dataclass(frozen=True)
class CheckResult:
    type: str
    people: tuple[int, ...]
    passed: bool
    value: float
    detail: str


# --------------------------------------------------------------------- measures
def facing_dirs(joints: np.ndarray) -> np.ndarray:
    """Unit horizontal facing directions (..., 2) as (x, z) from hips and shoulders."""
    r_hip, l_hip, r_sh, l_sh = FACE_JOINTS
    across = (joints[..., r_hip, :] - joints[..., l_hip, :]) + (
        joints[..., r_sh, :] - joints[..., l_sh, :]
    )
    # forward = up x across = (across_z, 0, -across_x)
    fwd = np.stack([across[..., 2], -across[..., 0]], axis=-1)
    return fwd / np.maximum(np.linalg.norm(fwd, axis=-1, keepdims=True), 1e-8)


def root_xz(joints: np.ndarray) -> np.ndarray:
    return joints[..., 0, [0, 2]]


def _angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    un = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-8)
    vn = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-8)
    return np.degrees(np.arccos(np.clip((un * vn).sum(-1), -1.0, 1.0)))


def facing_angle(joints: np.ndarray, a: int, b: int, frame: int = 0) -> float:
    """Angle (deg) between a's facing direction and the direction from a to b."""
    d = root_xz(joints[b, frame]) - root_xz(joints[a, frame])
    return float(_angle_deg(facing_dirs(joints[a, frame]), d))


def distance(joints: np.ndarray, a: int, b: int, frame: int = 0) -> float:
    return float(np.linalg.norm(root_xz(joints[b, frame]) - root_xz(joints[a, frame])))


def lateral_offset(joints: np.ndarray, a: int, b: int, frame: int = 0) -> tuple[float, float]:
    """b's position in a's frame: (left, forward) metres (left = +X when facing +Z)."""
    f = facing_dirs(joints[a, frame])  # (x, z)
    left = np.array([f[1], -f[0]])  # facing +Z (0,1) -> left +X (1,0)
    d = root_xz(joints[b, frame]) - root_xz(joints[a, frame])
    return float(d @ left), float(d @ f)


def closest_joints(
    a: np.ndarray, b: np.ndarray, within: float = np.inf
) -> tuple[float, int, np.ndarray]:
    """Smallest 3-D distance between any joint of body a and any of body b (T, 22, 3), its
    frame, and the floor direction (2,) from b's joint to a's there.

    Only frames where the two bodies could come ``within`` that distance are searched (at
    a frame, no two joints are closer than the pelvises' distance minus both bodies' reach
    from their pelvis). The result is exact when the bodies do come within it; otherwise
    it is only some value of at least ``within`` (the smallest bound, with the
    pelvis-to-pelvis direction, when no frame was searched).
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    reach_a = np.linalg.norm(a - a[:, :1], axis=-1).max(-1)
    reach_b = np.linalg.norm(b - b[:, :1], axis=-1).max(-1)
    bound = np.linalg.norm(a[:, 0] - b[:, 0], axis=-1) - reach_a - reach_b  # (T,)
    frames = np.flatnonzero(~(bound >= within))  # NaN frames are searched (and stay NaN)
    if len(frames) == 0:
        t = int(np.argmin(bound))
        return float(bound[t]), t, (a[t, 0] - b[t, 0])[[0, 2]]
    fa, fb = a[frames], b[frames]  # squared distances by |x|^2 + |y|^2 - 2 x.y: (F, 22, 22)
    d2 = (fa**2).sum(-1)[:, :, None] + (fb**2).sum(-1)[:, None, :] - 2.0 * fa @ fb.swapaxes(1, 2)
    f, i, j = np.unravel_index(int(np.argmin(d2)), d2.shape)
    diff = fa[f, i] - fb[f, j]
    return float(np.linalg.norm(diff)), int(frames[f]), diff[[0, 2]]


def min_interperson_distance(joints: np.ndarray) -> tuple[float, int, int, int]:
    """Smallest distance between any joints of two different people: (d, a, b, frame)."""
    best = (np.inf, -1, -1, -1)
    p = joints.shape[0]
    for a in range(p):
        for b in range(a + 1, p):
            d, t, _ = closest_joints(joints[a], joints[b])
            if d < best[0]:
                best = (d, a, b, t)
    return best


# Frames (0.5 s) over which the relation checks average each joint's position (relative to
# the pelvis) before they read when an action starts. Decoded motion shimmers by a few mm
# per joint per frame, and over a second of standing that adds up to as much motion as a
# bow: read frame to frame, a decoded action "started" 12-16 frames in whenever it did, and
# the VAE's own round trip of the real test scenes passed starts_after in 38 % of them
# (averaged over 15 frames: 100 %; the real scenes pass 100 % either way;
# research/vae_timing.py).
ONSET_SMOOTHING = 15


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """``x`` (T, ...) averaged over ``window`` frames centred on each (the ends repeated)."""
    if window <= 1:
        return x
    half = window // 2
    padded = np.concatenate([np.repeat(x[:1], half, 0), x, np.repeat(x[-1:], window - 1 - half, 0)])
    total = np.cumsum(np.concatenate([np.zeros_like(x[:1]), padded]), axis=0, dtype=np.float64)
    return ((total[window:] - total[:-window]) / window).astype(x.dtype)


def action_onset(joints: np.ndarray, fraction: float = 0.1, smooth: int = 1) -> int:
    """Frame at which a person's body motion (relative to the pelvis) really starts.

    The first frame by which ``fraction`` of the clip's total pose motion has happened;
    robust to mocap noise at rest, and cheap enough to run on every generated person.
    ``smooth`` > 1 averages the positions over that many frames first
    (:data:`ONSET_SMOOTHING`: what the checks read; the composer aligns real clips, which
    do not shimmer, frame to frame).
    """
    local = moving_average(joints - joints[:, :1, :], smooth)
    speed = np.linalg.norm(np.diff(local, axis=0), axis=-1).sum(-1)
    total = speed.sum()
    if total <= 1e-8:
        return 0
    return int(np.searchsorted(np.cumsum(speed), fraction * total))


# --------------------------------------------------------------------- checks
def check(joints: np.ndarray, c: dict[str, Any]) -> CheckResult:
    """Evaluate one constraint dict on a scene."""
    kind = c["type"]
    a, b = c.get("a", 0), c.get("b", 1)
    frame = c.get("frame", 0)
    if kind == "faces":
        ang = facing_angle(joints, a, b, frame)
        tol = c.get("tolerance_deg", FACING_TOLERANCE_DEG)
        return CheckResult(kind, (a, b), ang <= tol, ang, f"P{a} faces P{b}: {ang:.0f} deg")
    if kind == "faces_away":
        ang = facing_angle(joints, a, b, frame)
        tol = c.get("tolerance_deg", FACING_TOLERANCE_DEG)
        ok = ang >= 180.0 - tol
        return CheckResult(kind, (a, b), ok, ang, f"P{a} faces away from P{b}: {ang:.0f} deg")
    if kind == "distance":
        d = distance(joints, a, b, frame)
        ok = c["min"] <= d <= c["max"]
        return CheckResult(kind, (a, b), ok, d, f"P{a}-P{b} {d:.2f} m in [{c['min']}, {c['max']}]")
    if kind == "side":
        left, _ = lateral_offset(joints, a, b, frame)
        ok = left > SIDE_MARGIN if c["side"] == "left" else left < -SIDE_MARGIN
        return CheckResult(kind, (a, b), ok, left, f"P{b} on P{a}'s {c['side']}: {left:+.2f} m")
    if kind == "order":  # a is ahead of b along a's heading
        _, fwd = lateral_offset(joints, a, b, frame)
        return CheckResult(kind, (a, b), fwd < -0.5, fwd, f"P{b} behind P{a}: {fwd:+.2f} m")
    if kind == "same_heading":
        ang = float(_angle_deg(facing_dirs(joints[a, frame]), facing_dirs(joints[b, frame])))
        tol = c.get("tolerance_deg", SAME_HEADING_TOLERANCE_DEG)
        return CheckResult(kind, (a, b), ang <= tol, ang, f"P{a}/P{b} heading {ang:.0f} deg")
    if kind in ("approach", "retreat"):
        d0, d1 = distance(joints, a, b, 0), distance(joints, a, b, joints.shape[1] - 1)
        change = d1 - d0
        need = c.get("min_change", 0.5)
        ok = change <= -need if kind == "approach" else change >= need
        return CheckResult(kind, (a, b), ok, change, f"P{a}-P{b} distance {d0:.2f}->{d1:.2f} m")
    if kind == "starts_after":
        oa, ob = (action_onset(joints[k], smooth=ONSET_SMOOTHING) for k in (a, b))
        lag = ob - oa
        ok = lag >= c.get("min_frames", 8)
        return CheckResult(kind, (a, b), ok, float(lag), f"P{b} starts {lag} frames after P{a}")
    if kind == "no_contact":
        d, pa, pb, t = min_interperson_distance(joints)
        ok = d >= c.get("min_distance", CONTACT_DISTANCE)
        return CheckResult(kind, (pa, pb), ok, d, f"closest joints {d:.2f} m (P{pa}/P{pb}, f{t})")
    raise ValueError(f"unknown constraint type {kind!r}")


def check_record(joints: np.ndarray, record: dict[str, Any]) -> list[CheckResult]:
    """All constraints of a scene's relation record, evaluated on ``joints``."""
    if joints.shape[0] != record["num_people"]:
        raise ValueError(f"record has {record['num_people']} people, joints have {joints.shape[0]}")
    return [check(joints, c) for c in record["constraints"]]


def stature(joints: np.ndarray) -> float:
    """Median head-joint height above the lowest foot joint over frames (m): the body's
    size that closeness is measured in."""
    j = np.asarray(joints, dtype=np.float64).reshape(-1, 22, 3)
    return float(np.median(j[:, 15, 1] - j[:, [7, 8, 10, 11], 1].min(-1)))


def pair_closeness(joints: np.ndarray, a: int = 0, b: int = 1) -> dict[str, float]:
    """How close two people (P, T, 22, 3) are, frame by frame, summarised.

    ``hands_near``: fraction of frames where some wrist of one is within 0.3 x stature of
    some wrist of the other; ``pelvis``: median floor distance of the pelvises over stature
    (and in metres); ``facing``: median cosine between a's facing and the direction to b,
    and b's to a, averaged (1: face to face); ``hands_m``: median nearest-wrists distance;
    ``min_joint_m``: the closest any two joints of the two bodies come (the inter-person
    penetration reference: real partners keep this above a few centimetres); ``closest_p05_m``
    and ``pelvis_p05_m``: the 5th percentiles over frames of the closest-joints and pelvis
    distances, what a clean-up may let generated partners come to."""
    j = np.asarray(joints, dtype=np.float64)
    size = 0.5 * (stature(j[a]) + stature(j[b]))
    wa, wb = j[a][:, [20, 21]], j[b][:, [20, 21]]
    hands = np.linalg.norm(wa[:, :, None] - wb[:, None], axis=-1).min((1, 2))
    d = root_xz(j[b]) - root_xz(j[a])
    pelvis = np.linalg.norm(d, axis=-1)
    unit = d / np.maximum(pelvis[:, None], 1e-8)
    face = 0.5 * ((facing_dirs(j[a]) * unit).sum(-1) + (facing_dirs(j[b]) * -unit).sum(-1))
    pa, pb = j[a], j[b]  # closest joints frame by frame: (T, 22, 22) distances
    closest = np.linalg.norm(pa[:, :, None] - pb[:, None], axis=-1).min((1, 2))
    return {
        "stature_m": round(size, 4),
        "hands_near": round(float((hands < 0.3 * size).mean()), 4),
        "hands_m": round(float(np.median(hands)), 4),
        "pelvis": round(float(np.median(pelvis)) / size, 4),
        "pelvis_m": round(float(np.median(pelvis)), 4),
        "facing": round(float(np.median(face)), 4),
        "min_joint_m": round(float(closest.min()), 4),
        "closest_p05_m": round(float(np.percentile(closest, 5)), 4),
        "pelvis_p05_m": round(float(np.percentile(pelvis, 5)), 4),
    }


# share of a take's frames with hands near (pair_closeness) from which its people touch
TOUCHING_HANDS = 0.25


def measured_relation(joints: np.ndarray) -> dict[str, Any]:
    """The relation record of a real take, measured on its motion: person 1 against each
    other person (:func:`pair_closeness`), and whether they touch (hands near in at least
    :data:`TOUCHING_HANDS` of the frames, for person 1 and someone), so the clean-up and the
    checks can keep such people close. The one rule for "a take whose people touch": the
    importer's record, the vocabulary's ``contact`` and the bank's touching crops read it."""
    pairs = {f"1-{k + 1}": pair_closeness(joints, 0, k) for k in range(1, joints.shape[0])}
    touch = any(p["hands_near"] >= TOUCHING_HANDS for p in pairs.values())
    return {"kind": "real-take", "pairs": pairs, "touching": bool(touch)}
