"""Body capsules: one per bone, and how deep two people's capsules overlap.

The evaluation's inter-person penetration (:mod:`umf.eval.physics`) and the clean-up's
untangling of couples who touch (:mod:`umf.untangle`) measure bodies the same way, so the
geometry lives below both.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from umf.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS

# One capsule per bone, named by its child joint (bone j runs from PARENTS[j] to j).
# Radii (m) are a slim adult: about the half-thickness of each body part, so that two
# real people standing close do not overlap; hands and the top of the skull are not
# covered (the skeleton ends at the wrists and the head joint), which keeps the measure
# conservative: what it reports as penetration is really penetration.
BONE_RADII: dict[str, float] = {
    "l_hip": 0.09, "r_hip": 0.09,  # pelvis -> hips: the pelvis block
    "spine1": 0.11, "spine2": 0.11, "spine3": 0.11,  # abdomen and chest (half depth)
    "l_knee": 0.07, "r_knee": 0.07,  # thighs
    "l_ankle": 0.05, "r_ankle": 0.05,  # shins
    "l_foot": 0.04, "r_foot": 0.04,  # feet (ankle -> toes)
    "neck": 0.05,
    "l_collar": 0.06, "r_collar": 0.06,  # upper chest to the shoulder line
    "head": 0.10,  # neck -> head joint
    "l_shoulder": 0.055, "r_shoulder": 0.055,  # collar -> shoulder
    "l_elbow": 0.045, "r_elbow": 0.045,  # upper arms
    "l_wrist": 0.035, "r_wrist": 0.035,  # forearms
}  # fmt: skip
_BONE_CHILDREN = np.arange(1, NUM_JOINTS)
_BONE_PARENTS = np.array(PARENTS[1:])


def bone_radii() -> np.ndarray:
    """Capsule radii (21,) in bone order (bone j-1 ends at joint j)."""
    return np.array([BONE_RADII[JOINT_NAMES[j]] for j in _BONE_CHILDREN])


def as_numpy(joints: Any) -> np.ndarray:
    """float64 array from numpy or (CPU) torch joints."""
    if hasattr(joints, "detach"):
        joints = joints.detach().cpu().numpy()
    return np.asarray(joints, dtype=np.float64)


# --------------------------------------------------------------------- geometry
def closest_points(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray, eps: float = 1e-12
) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (s, t) in [0, 1] of the closest points p1 + s (q1 - p1) and p2 + t (q2 -
    p2) of two segments (broadcast over leading axes).

    Ericson, *Real-Time Collision Detection*, 5.1.9: minimise over the two segment
    parameters, clamp, and re-project. Parallel segments (zero determinant) take
    s = 0 and are then clamped like the general case, which is exact for them too;
    zero-length segments degrade to point-segment and point-point distances.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    b = (d1 * d2).sum(-1)
    c = (d1 * r).sum(-1)
    f = (d2 * r).sum(-1)
    a_ok, e_ok = a > eps, e > eps
    safe_a, safe_e = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    parallel = denom <= eps * np.maximum(a * e, eps)
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0, 1))
    t = (b * s + f) / safe_e
    s = np.where(
        t < 0, np.clip(-c / safe_a, 0, 1), np.where(t > 1, np.clip((b - c) / safe_a, 0, 1), s)
    )
    t = np.clip(t, 0, 1)
    # degenerate segments: a point against a segment, or two points
    s = np.where(a_ok, s, 0.0)
    t = np.where(a_ok, t, np.clip(f / safe_e, 0, 1))
    s = np.where(~e_ok & a_ok, np.clip(-c / safe_a, 0, 1), s)
    t = np.where(e_ok, t, 0.0)
    return s, t


def segment_distance(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray, eps: float = 1e-12
) -> np.ndarray:
    """Closest distance between segments p1-q1 and p2-q2 (broadcast over leading axes):
    :func:`closest_points`."""
    s, t = closest_points(p1, q1, p2, q2, eps)
    gap = (p1 + (q1 - p1) * s[..., None]) - (p2 + (q2 - p2) * t[..., None])
    return np.sqrt((gap * gap).sum(-1))


def _candidates(a: np.ndarray, b: np.ndarray):
    """The (frame, bone of a, bone of b) triples whose capsules may overlap, by two exact
    culls, and the bones' end points: frames whose bounding spheres (around the pelvis,
    through the farthest joint plus the largest radius) touch, and bone pairs whose
    midpoint distance minus both half lengths (a lower bound of the segment distance) is
    under their radii sum."""
    radii = bone_radii()
    reach_a = np.linalg.norm(a - a[:, :1], axis=-1).max(-1) + radii.max()
    reach_b = np.linalg.norm(b - b[:, :1], axis=-1).max(-1) + radii.max()
    near = np.flatnonzero(np.linalg.norm(a[:, 0] - b[:, 0], axis=-1) < reach_a + reach_b)
    pa, qa = a[near][:, _BONE_PARENTS], a[near][:, _BONE_CHILDREN]  # (T', 21, 3)
    pb, qb = b[near][:, _BONE_PARENTS], b[near][:, _BONE_CHILDREN]
    mid_gap = np.linalg.norm((pa + qa)[:, :, None] - (pb + qb)[:, None], axis=-1) / 2
    half_a = np.linalg.norm(qa - pa, axis=-1) / 2
    half_b = np.linalg.norm(qb - pb, axis=-1) / 2
    reach = radii[:, None] + radii[None, :]
    lower = mid_gap - half_a[:, :, None] - half_b[:, None, :]
    t, i, j = np.nonzero(lower < reach)
    return near, t, i, j, (pa, qa, pb, qb), reach


def capsule_penetration(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Deepest capsule overlap (T,) in metres between two people a, b (T, 22, 3).

    Per frame: max over the 21 x 21 bone pairs of (radius_i + radius_j - segment
    distance), clipped at 0 (only the pairs :func:`_candidates` keeps are measured).
    """
    a, b = as_numpy(a), as_numpy(b)
    out = np.zeros(a.shape[0])
    near, t, i, j, (pa, qa, pb, qb), reach = _candidates(a, b)
    if t.size == 0:
        return out
    depth = reach[i, j] - segment_distance(pa[t, i], qa[t, i], pb[t, j], qb[t, j])
    deepest = np.zeros(near.size)
    np.maximum.at(deepest, t, depth)
    out[near] = deepest
    return out


def overlaps(a: np.ndarray, b: np.ndarray) -> dict[str, np.ndarray]:
    """Every overlapping pair of capsules of person a with person b (T, 22, 3): ``frame``,
    ``bone`` (of a; bone k - 1 ends at joint k), ``along`` (where on a's bone the closest
    point lies, 0 at its parent joint, 1 at its child), ``depth`` (m) and ``normal`` (unit,
    from b's closest point to a's: the way a must move to get out)."""
    a, b = as_numpy(a), as_numpy(b)
    near, t, i, j, (pa, qa, pb, qb), reach = _candidates(a, b)
    s, u = closest_points(pa[t, i], qa[t, i], pb[t, j], qb[t, j])
    on_a = pa[t, i] + (qa[t, i] - pa[t, i]) * s[:, None]
    on_b = pb[t, j] + (qb[t, j] - pb[t, j]) * u[:, None]
    gap = on_a - on_b
    dist = np.linalg.norm(gap, axis=-1)
    depth = reach[i, j] - dist
    # bones that cross have no closest-point direction: take their midpoints', and where
    # those coincide too, the pelvises'
    for fallback in (
        (pa[t, i] + qa[t, i] - pb[t, j] - qb[t, j]) / 2,
        a[near][t, 0] - b[near][t, 0],
    ):
        flat = np.linalg.norm(gap, axis=-1) < 1e-9
        gap[flat] = fallback[flat]
    keep = depth > 0
    normal = gap[keep] / np.maximum(np.linalg.norm(gap[keep], axis=-1), 1e-9)[:, None]
    return {"frame": near[t[keep]], "bone": i[keep], "along": s[keep], "depth": depth[keep],
            "normal": normal}  # fmt: skip
