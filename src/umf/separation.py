"""Keep generated people apart: a rigid shift on the floor, never a change of the motion.

S-Flow is trained on two-person scenes; asked for a third or fourth person it can place
several reactions on top of each other (they share the same context). An animator wants
bodies that do not overlap, so the pipeline, by default, moves each person k >= 2 as a
whole along the floor, as little as needed, until at every frame their pelvis keeps
``min_distance`` from everyone before them (on the floor) and none of their joints comes
within ``contact_distance`` of another person's joint: the training scenes' own rule (the
composer keeps people 25 cm apart), so hands and elbows do not pass through a neighbour.
Person 1 never moves (in ``react`` mode it is the user's own motion), and each person's
motion is unchanged up to that one translation. People the data holds close (a prompt worded
like the caption of a real take whose partners touch, such as CMU's salsa couples) may come
as close as real partners ever do instead (:func:`touching_distances`: joints 2 cm, pelvises
0.2 m), and their shift is the shortest found that clears (``smallest``). The take's 5th
percentiles, held at every frame as before 20261213, moved 61 of 156 four-second crops of
the real salsa takes themselves by more than 2 cm, up to 82 cm; these floors move none
(research/touch_shifts.py). Evaluation turns it off (``separate=False``) to score the
model's own output.
"""

from __future__ import annotations

import numpy as np

from umf.data.relations import CONTACT_DISTANCE, closest_joints

__all__ = [
    "CONTACT_DISTANCE",
    "FIT_MARGIN",
    "MIN_DISTANCE",
    "TOUCH_FLOOR",
    "TOUCH_PELVIS",
    "separate_people",
]

MIN_DISTANCE = 0.5  # metres between two pelvises on the floor: shoulder to shoulder
STEP_MARGIN = 0.01  # m pushed beyond what is missing: fewer rounds when the worst pair changes
TOUCH_FLOOR = 0.02  # m: the least joint distance allowed between people who touch (a held
# hand's wrists); the real salsa takes' closest joints come to 1.0-6.7 cm at the least
TOUCH_PELVIS = 0.2  # m on the floor between the pelvises of people who touch: the real
# salsa partners' come no closer than 0.21 m (two torsos, not one inside the other)
FIT_MARGIN = 0.03  # m added to the contact distance: the kinematic fit that follows moves
# joints by up to a few centimetres (umf.kinematics), and they must still not touch


def closest_approach(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Smallest floor distance between two pelvis paths (T, 2) and the frame where it is."""
    d = np.linalg.norm(a - b, axis=-1)
    t = int(np.argmin(d))
    return float(d[t]), t


def _deficit(
    k: int,
    j: int,
    pelvis: np.ndarray,
    bodies: np.ndarray | None,
    shifts: np.ndarray,
    min_distance: float,
    contact_distance: float,
) -> tuple[float, np.ndarray]:
    """How far person k must still move away from person j, and which way on the floor:
    along the line between their pelvises at the frame where they are closest (between the
    two touching joints when the pelvises coincide)."""
    path, other = pelvis[k] + shifts[k], pelvis[j] + shifts[j]
    d, t = closest_approach(path, other)
    worst, way = min_distance - d, path[t] - other[t]
    if bodies is not None:
        lift = np.zeros(3)
        lift[[0, 2]] = shifts[k] - shifts[j]
        d, t, joint_way = closest_joints(bodies[k] + lift, bodies[j], contact_distance)
        if contact_distance - d > worst:
            worst, way = contact_distance - d, path[t] - other[t]
            way = way if np.linalg.norm(way) > 1e-6 else joint_way
    return worst, way


def separation_shifts(
    pelvis: np.ndarray,
    min_distance: float = MIN_DISTANCE,
    max_rounds: int = 10,
    bodies: np.ndarray | None = None,
    contact_distance: float = CONTACT_DISTANCE,
    smallest: bool = False,
) -> np.ndarray:
    """Floor offsets (N, 2) that keep pelvis paths (N, T, 2) ``min_distance`` apart and,
    given ``bodies`` (N, T, 22, 3), every two people's joints ``contact_distance`` apart.

    People are placed in order (as Algorithm 1 generates them); person k is pushed away
    from every earlier person it is too close to at once (each push along the line between
    the two pelvises at the frame where they are closest, as far as is missing plus
    ``STEP_MARGIN``), until it clears all of them. Coincident paths are split along a fixed,
    person-dependent direction so the result is deterministic. ``smallest``: then look for
    a shorter shift that also clears them (:func:`_shorter_shift`), for people who should
    stay as close as they may: the push follows the worst frame, and the way out nearest
    to where the person was is often another.
    """
    n = pelvis.shape[0]
    shifts = np.zeros((n, 2))

    def push_of(k: int) -> np.ndarray | None:
        """Sum over everyone k is too close to of (how far) x (which way); None: clear."""
        total, any_ = np.zeros(2), False
        for j in range(k):
            need, way = _deficit(k, j, pelvis, bodies, shifts, min_distance, contact_distance)
            if need > 0:
                any_ = True
                if np.linalg.norm(way) < 1e-6:
                    angle = 2.0 * np.pi * k / (n + 1)
                    way = np.array([np.cos(angle), np.sin(angle)])
                total += way / np.linalg.norm(way) * (need + STEP_MARGIN)
        return total if any_ else None

    for k in range(1, n):
        for _ in range(max_rounds):
            push = push_of(k)
            if push is None or np.linalg.norm(push) < 1e-6:  # clear, or pushes cancel out
                break
            shifts[k] += push
        step = max(min_distance, contact_distance if bodies is not None else 0.0, 0.04) / 4
        _walk_out(pelvis, shifts, k, step, lambda k=k: push_of(k) is None)
        if smallest and np.isfinite(shifts[k]).all():
            _shorter_shift(shifts, k, lambda k=k: push_of(k) is None)
    return shifts


DIRECTIONS = 36  # ways out a shorter shift is looked for along (every 10 degrees)
HALVINGS = 6  # bisection steps per direction: to 1/64 of the push's length


def _shorter_shift(shifts: np.ndarray, k: int, clear) -> None:
    """Replace person k's shift (which clears everyone, by ``clear``) by the shortest that
    still does among ``DIRECTIONS`` directions, each bisected ``HALVINGS`` times between no
    shift and the push's length; only shifts that ``clear`` confirms are taken."""
    push = shifts[k].copy()
    best = float(np.linalg.norm(push))
    if best < 1e-9 or not clear():
        return
    for angle in np.linspace(0.0, 2.0 * np.pi, DIRECTIONS, endpoint=False):
        way = np.array([np.cos(angle), np.sin(angle)])
        shifts[k] = way * best
        if not clear():  # no way out along here within the push's length
            continue
        lo, hi = 0.0, best
        for _ in range(HALVINGS):
            shifts[k] = way * (lo + hi) / 2
            lo, hi = (lo, (lo + hi) / 2) if clear() else ((lo + hi) / 2, hi)
        if hi < best:
            best, push = hi, way * hi
    shifts[k] = push


def _walk_out(pelvis: np.ndarray, shifts: np.ndarray, k: int, step: float, clear) -> None:
    """Pushes between two neighbours can cycle in a crowd: then move person k straight away
    from the others' centre until it clears all of them (always ends: they are finite)."""
    if clear() or not np.isfinite(pelvis[: k + 1]).all():  # NaN never clears: leave it
        return
    centre = np.mean([(pelvis[j] + shifts[j]).mean(0) for j in range(k)], axis=0)
    away = (pelvis[k] + shifts[k]).mean(0) - centre
    if np.linalg.norm(away) < 1e-6:
        angle = 2.0 * np.pi * k / (k + 2)
        away = np.array([np.cos(angle), np.sin(angle)])
    away = away / np.linalg.norm(away)
    while not clear():
        shifts[k] += away * step


def separate_people(
    joints: np.ndarray,
    min_distance: float = MIN_DISTANCE,
    contact_distance: float = CONTACT_DISTANCE + FIT_MARGIN,
    smallest: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (N, T, 22, 3) with people k >= 2 shifted apart on the floor, and the (N, 3)
    shifts applied (zero rows for people who did not move); ``smallest``: as
    :func:`separation_shifts`."""
    bodies = joints.astype(np.float64)
    flat = separation_shifts(bodies[:, :, 0, [0, 2]], min_distance, bodies=bodies,
                             contact_distance=contact_distance, smallest=smallest)  # fmt: skip
    shifts = np.zeros((joints.shape[0], 3), dtype=joints.dtype)
    shifts[:, 0], shifts[:, 2] = flat[:, 0], flat[:, 1]
    return joints + shifts[:, None, None, :], shifts


def touching_distances(contact: dict | None) -> dict[str, float | bool]:
    """:func:`separate_people`'s distances: its defaults, or for a prompt worded like a
    touching take (``contact``: :mod:`umf.coverage`), the least real partners keep at any
    frame, :data:`TOUCH_FLOOR` between joints and :data:`TOUCH_PELVIS` between pelvises:
    partners may hold hands and dance as close as the takes do, but one torso does not stand
    inside the other. Joints only, on the decoded motion: limbs may still cross, and the fit
    that follows may bring two joints a little closer (no :data:`FIT_MARGIN` here, or real
    takes would be pushed apart)."""
    if not contact:
        return {}
    return {"min_distance": TOUCH_PELVIS, "contact_distance": TOUCH_FLOOR, "smallest": True}
