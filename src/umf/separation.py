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
like the caption of a real take whose partners touch, such as CMU's salsa couples) keep the
closeness of that take instead (:func:`touching_distances`): they may come as close as the
take's people do, as often (its 5th percentiles over frames, ``quantile``), never closer
than :data:`TOUCH_FLOOR` at any frame, and their shift is the shortest found that clears
(``smallest``). Judged by the take's closest frame instead, the rule pushed every real salsa
take itself apart (research/touch_shifts.py). Evaluation turns it off (``separate=False``)
to score the model's own output.
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
    "TOUCH_QUANTILE",
    "separate_people",
]

MIN_DISTANCE = 0.5  # metres between two pelvises on the floor: shoulder to shoulder
STEP_MARGIN = 0.01  # m pushed beyond what is missing: fewer rounds when the worst pair changes
TOUCH_FLOOR = 0.02  # m: the least joint distance allowed at any frame between people who
# touch (a held hand's wrists); real salsa partners' closest joints stay above it in 95 % of
# frames
TOUCH_PELVIS = 0.2  # m on the floor between the pelvises of people who touch, at every
# frame: real salsa partners' come no closer than 0.21 m (two torsos, not one inside another)
TOUCH_QUANTILE = 0.05  # people who touch are judged at this quantile of their frames: as
# the take's own closeness is measured (umf.coverage.take_contacts)
FIT_MARGIN = 0.03  # m added to the contact distance: the kinematic fit that follows moves
# joints by up to a few centimetres (umf.kinematics), and they must still not touch


def closest_approach(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Smallest floor distance between two pelvis paths (T, 2) and the frame where it is."""
    d = np.linalg.norm(a - b, axis=-1)
    t = int(np.argmin(d))
    return float(d[t]), t


def at_quantile(d: np.ndarray, quantile: float) -> int:
    """The frame whose value of ``d`` (T,) is the ``quantile``-th over frames (the nearest
    rank, as ``np.percentile(..., method="nearest")``; NaN frames last): 0 is the smallest."""
    order = np.argsort(d)
    return int(order[int(np.rint(quantile * (len(d) - 1)))])


def closest_each_frame(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest joints of bodies a and b (T, 22, 3) frame by frame: distances (T,) and the
    floor directions (T, 2) from b's joint to a's."""
    diff = a[:, :, None] - b[:, None]  # (T, 22, 22, 3)
    d = np.linalg.norm(diff, axis=-1).reshape(len(a), -1)
    pick = d.argmin(-1)
    way = diff.reshape(len(a), -1, 3)[np.arange(len(a)), pick][:, [0, 2]]
    return d[np.arange(len(a)), pick], way


def _deficit(
    k: int,
    j: int,
    pelvis: np.ndarray,
    bodies: np.ndarray | None,
    shifts: np.ndarray,
    min_distance: float,
    contact_distance: float,
    quantile: float = 0.0,
    floor: float = 0.0,
) -> tuple[float, np.ndarray]:
    """How far person k must still move away from person j, and which way on the floor:
    along the line between their pelvises at the frame where they are closest (between the
    two touching joints when the pelvises coincide). ``quantile`` > 0: the distances are
    read at that quantile of the frames rather than at the closest one, and at every frame
    the joints must still keep ``floor`` and the pelvises :data:`TOUCH_PELVIS`."""
    path, other = pelvis[k] + shifts[k], pelvis[j] + shifts[j]
    if quantile > 0:
        apart = np.linalg.norm(path - other, axis=-1)
        t = at_quantile(apart, quantile)
        d = float(apart[t])
        if TOUCH_PELVIS - apart.min() > min_distance - d:
            t = int(apart.argmin())
            d = float(apart[t]) + min_distance - TOUCH_PELVIS
    else:
        d, t = closest_approach(path, other)
    worst, way = min_distance - d, path[t] - other[t]
    if bodies is not None:
        lift = np.zeros(3)
        lift[[0, 2]] = shifts[k] - shifts[j]
        if quantile > 0:
            near, ways = closest_each_frame(bodies[k] + lift, bodies[j])
            t = at_quantile(near, quantile)
            need = [(contact_distance - near[t], t), (floor - near.min(), int(near.argmin()))]
            gap, t = max(need)
            d, joint_way = contact_distance - gap, ways[t]
        else:
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
    quantile: float = 0.0,
    floor: float = 0.0,
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
    to where the person was is often another. ``quantile``, ``floor``: people who may touch,
    judged at that quantile of their frames and kept ``floor`` apart at every frame
    (:func:`_deficit`).
    """
    n = pelvis.shape[0]
    shifts = np.zeros((n, 2))

    def push_of(k: int) -> np.ndarray | None:
        """Sum over everyone k is too close to of (how far) x (which way); None: clear."""
        total, any_ = np.zeros(2), False
        for j in range(k):
            need, way = _deficit(k, j, pelvis, bodies, shifts, min_distance, contact_distance,
                                 quantile, floor)  # fmt: skip
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
    quantile: float = 0.0,
    floor: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (N, T, 22, 3) with people k >= 2 shifted apart on the floor, and the (N, 3)
    shifts applied (zero rows for people who did not move); ``smallest``, ``quantile``,
    ``floor``: as :func:`separation_shifts`."""
    bodies = joints.astype(np.float64)
    flat = separation_shifts(bodies[:, :, 0, [0, 2]], min_distance, bodies=bodies,
                             contact_distance=contact_distance, smallest=smallest,
                             quantile=quantile, floor=floor)  # fmt: skip
    shifts = np.zeros((joints.shape[0], 3), dtype=joints.dtype)
    shifts[:, 0], shifts[:, 2] = flat[:, 0], flat[:, 1]
    return joints + shifts[:, None, None, :], shifts


def touching_distances(contact: dict | None) -> dict[str, float | bool]:
    """:func:`separate_people`'s distances: its defaults, or for a prompt worded like a
    touching take, that take's closeness, read as the take's is (the 5th percentiles of
    its frames, :data:`TOUCH_QUANTILE`), and never closer than :data:`TOUCH_FLOOR` between
    joints nor :data:`TOUCH_PELVIS` between pelvises at any frame: bodies still must not
    pass through each other."""
    if not contact:
        return {}
    closest = max(float(contact.get("closest_m", CONTACT_DISTANCE)), TOUCH_FLOOR)
    return {"min_distance": min(MIN_DISTANCE, float(contact.get("pelvis_m", MIN_DISTANCE))),
            "contact_distance": min(CONTACT_DISTANCE, closest), "smallest": True,
            "quantile": TOUCH_QUANTILE, "floor": TOUCH_FLOOR}  # fmt: skip
