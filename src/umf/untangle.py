"""Bones moved out of a partner's body, frame by frame, their lengths kept.

A couple that touches (a prompt worded like a real salsa take) may stand as close as real
partners do (:func:`umf.separation.touching_distances`), and the flows then often put an
arm through the partner's chest or a thigh through the partner's thigh: over seeds 0-31
the generated salsa couples' body capsules overlapped 1.51 cm on average, the real test
and val takes' 0.39. Shifting a whole person apart clears that only by taking the hands
apart too (results/umf-small-bandai-20261219, "Tried"). :func:`untangle` instead moves the
overlapping bones: each capsule of person k that overlaps one of persons 1..k - 1 pushes
its two joints out along the contact normal, as far as the overlap is deep (shared by where
along the bone it touches, at most :data:`MAX_PUSH`), the push fades in and out over
neighbouring frames and is averaged over a few (so the body does not shake as the depth
changes from frame to frame), and the refinement of :mod:`umf.kinematics` (bone lengths
fixed, the pelvis' floor path kept) moves the body towards those targets, the rest of the
pose held where it is. Several rounds, since one push can make another contact and the
averaging leaves part of a deep one: over seeds 0-31, 0.41 cm on average remain."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from umf.capsules import _BONE_CHILDREN, _BONE_PARENTS, overlaps
from umf.kinematics import Bodies, refine
from umf.skeleton import NUM_JOINTS

ROUNDS = 8  # push-and-refine rounds per person (salsa, seeds 0-31: 3 left 0.64 cm, 8 0.41)
MARGIN = 0.005  # m pushed beyond the overlap: the refinement lands a little short
SPREAD = 5  # frames each side a push fades over (a triangle): no jerk where it starts
SMOOTH = 2  # frames each side the pushes are then averaged over (a triangle): an overlap's
# depth changes from frame to frame, and pushes that follow it made the couple 12 % jerkier
PUSH_WEIGHT = 4.0  # a pushed joint's target counts this many times a held one's
MAX_PUSH = 0.05  # m a joint is pushed at most per round: a body deep in the partner's is
# moved out over the rounds, not flung (uncapped, a knee moved 41 cm in one salsa seed)
ITERATIONS = 4  # Levenberg-Marquardt steps per round


def pushes(own: np.ndarray, others: Sequence[np.ndarray], margin: float = MARGIN) -> np.ndarray:
    """(T, 22, 3): how far each joint of a person ``own`` (T, 22, 3) should move so that
    none of its capsules overlaps those of ``others`` (each (T, 22, 3)), before spreading:
    every overlapping pair pushes its bone's parent joint by (1 - along) and its child by
    ``along`` of the overlap's depth plus ``margin``, along the normal; a joint pushed by
    several takes the largest push, at most :data:`MAX_PUSH`. The pelvis is never pushed
    (where a person stands is the separation's, :mod:`umf.separation`)."""
    out = np.zeros(own.shape)
    size = np.zeros(own.shape[:2])
    for other in others:
        hit = overlaps(own, other)
        push = hit["normal"] * (hit["depth"] + margin)[:, None]
        along = hit["along"][:, None]
        frame = np.concatenate([hit["frame"], hit["frame"]])
        joint = np.concatenate([_BONE_PARENTS[hit["bone"]], _BONE_CHILDREN[hit["bone"]]])
        part = np.concatenate([push * (1 - along), push * along])
        length = np.linalg.norm(part, axis=-1)
        # per (frame, joint): the longest push, the first of equals
        key = frame * NUM_JOINTS + joint
        order = np.lexsort((np.arange(key.size), -length, key))
        first = order[np.r_[True, key[order][1:] != key[order][:-1]]] if key.size else order
        win = first[length[first] > size[frame[first], joint[first]]]
        size[frame[win], joint[win]] = length[win]
        out[frame[win], joint[win]] = part[win]
    out *= np.minimum(1.0, MAX_PUSH / np.maximum(size, 1e-12))[..., None]
    out[:, 0] = 0.0
    return out


def spread(push: np.ndarray, frames: int | None = None) -> np.ndarray:
    """Pushes (T, 22, 3) faded in and out over ``frames`` each side (default
    :data:`SPREAD`): a joint that has a push of its own at a frame keeps it whole; one that
    has none takes the largest of its neighbours' pushes scaled by a triangle (1 at their
    frame, 0 at ``frames`` + 1 away)."""
    frames = SPREAD if frames is None else frames
    out = push.copy()
    own = np.abs(push).sum(-1) > 0
    size = np.linalg.norm(push, axis=-1)
    for lag in range(1, frames + 1):
        w = 1.0 - lag / (frames + 1)
        later, earlier = slice(lag, None), slice(None, -lag)
        for src, dst in ((later, earlier), (earlier, later)):
            cand = push[src] * w
            length = np.linalg.norm(cand, axis=-1)
            take = (length > size[dst]) & ~own[dst]
            out[dst][take] = cand[take]
            size[dst] = np.where(take, length, size[dst])
    return out


def smooth(push: np.ndarray, width: int | None = None) -> np.ndarray:
    """Pushes (T, 22, 3) averaged over ``width`` frames each side (default :data:`SMOOTH`)
    with triangle weights, the first and last frames held beyond the ends."""
    width = SMOOTH if width is None else width
    if width == 0 or push.shape[0] == 0:
        return push.copy()
    kernel = np.array([width + 1.0 - abs(i) for i in range(-width, width + 1)])
    kernel /= kernel.sum()
    padded = np.pad(push, ((width, width), (0, 0), (0, 0)), mode="edge")
    return sum(w * padded[i : i + push.shape[0]] for i, w in enumerate(kernel))


def _person(bodies: Bodies, k: int) -> np.ndarray:
    """Person k's joints (T, 22, 3): the forward kinematics of that one body."""
    one = slice(k, k + 1)
    return Bodies(bodies.offsets[one], bodies.rotations[one], bodies.root[one]).joints()[0]


def untangle(
    bodies: Bodies,
    movable: Sequence[bool] | bool = True,
    floor: float | None = 0.0,
    rounds: int = ROUNDS,
) -> Bodies:
    """``bodies`` with each person k >= 2 marked ``movable`` moved bone by bone out of
    persons 1..k - 1 (person 1 never moves: in ``react`` it is the user's own motion).
    Frames more than :data:`SPREAD` + :data:`SMOOTH` frames from any overlap are left
    exactly as they were; with ``floor``, a moved frame whose lowest joint a push took
    under it is lifted back onto it."""
    n = bodies.num_people
    flags = [bool(movable)] * n if isinstance(movable, bool) else [bool(m) for m in movable]
    if len(flags) != n:
        raise ValueError(f"movable names {len(flags)} people, the bodies hold {n}")
    out = Bodies(bodies.offsets.copy(), bodies.rotations.copy(), bodies.root.copy())
    for k in range(1, n):
        if not flags[k]:
            continue
        touched = np.zeros(out.num_frames, dtype=bool)
        before = list(out.joints()[:k])  # persons 1..k - 1 hold still while k moves
        for _ in range(rounds):
            own = _person(out, k)
            push = smooth(spread(pushes(own, before)))
            moved = np.flatnonzero(np.abs(push).sum((1, 2)) > 0)
            if moved.size == 0:
                break
            target = own[moved] + push[moved]
            weight = np.where(np.abs(push[moved]).sum(-1) > 0, PUSH_WEIGHT, 1.0)
            local, root = refine(
                torch.from_numpy(out.rotations[k, moved]),
                torch.from_numpy(out.root[k, moved]),
                torch.from_numpy(out.offsets[k])[None].expand(moved.size, NUM_JOINTS, 3),
                torch.from_numpy(target),
                torch.from_numpy(weight),
                ITERATIONS,
            )
            out.rotations[k, moved] = local.numpy()
            out.root[k, moved] = root.numpy()
            touched[moved] = True
        if floor is not None and touched.any():
            lowest = _person(out, k)[touched, :, 1].min(-1)
            out.root[k, touched, 1] += np.maximum(floor - lowest, 0.0)
    return out
