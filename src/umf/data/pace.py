"""Keeping pace: for people who walk or run together, how fast a clip moves forward, where
its strides fall, and where to cut it so that everybody starts in step
(:mod:`umf.data.scene_relations` lays out the paced relations with these; the composer
draws partners at the leader's pace)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from umf.data.clip import FPS
from umf.data.relations import facing_dirs
from umf.data.scenes import MAX_FRAMES, MIN_FRAMES, Actor, forward_travel
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT

PACE_TOLERANCE = 0.15  # m/s between mean forward speeds: under 0.6 m apart after 4 s


def pace(actor: Actor) -> float:
    """Mean forward speed (m/s) from the first left stride (where a paced scene cuts the
    clip, :func:`in_step`) over at most ``MAX_FRAMES`` frames: the clip's own pace, not that
    of the window a scene plays, which also ends with its partners' clips."""
    start = stride_start(actor.joints)
    travel = forward_travel(actor.joints[start : start + MAX_FRAMES])
    return float(travel[-1]) / max(len(travel) - 1, 1) * FPS


def partners_at_pace(
    leader: Actor, pool: Sequence[Actor], paces: dict[str, float], tolerance: float = PACE_TOLERANCE
) -> list[Actor]:
    """The clips of ``pool`` other than ``leader`` whose mean forward speed is within
    ``tolerance`` m/s of the leader's. ``paces`` memoises :func:`pace` by clip id across the
    calls of one composition (a pool is measured once, not at every scene drawn)."""

    def of(a: Actor) -> float:
        if a.id not in paces:
            paces[a.id] = pace(a)
        return paces[a.id]

    return [a for a in pool if a is not leader and abs(of(a) - of(leader)) <= tolerance]


def left_strides(joints: np.ndarray, reach: float = 0.1) -> np.ndarray:
    """Frames where the left foot is furthest ahead of the right along the body's facing
    (local maxima above ``reach`` metres): the phase of a walk or a run, (K,)."""
    fwd = facing_dirs(joints)
    sep = joints[:, FOOT_LEFT[1], :][:, [0, 2]] - joints[:, FOOT_RIGHT[1], :][:, [0, 2]]
    s = np.sum(sep * fwd, axis=-1)
    peak = (s[1:-1] >= s[:-2]) & (s[1:-1] > s[2:]) & (s[1:-1] > reach)
    return np.flatnonzero(peak) + 1


def stride_start(joints: np.ndarray, nth: int = 0) -> int:
    """The ``nth`` left stride of a clip (0: the first), where a paced scene starts it; 0 for
    a clip without that stride, or with too few frames after it."""
    strides = left_strides(joints)[nth : nth + 1]
    return int(strides[0]) if strides.size and len(joints) - strides[0] >= MIN_FRAMES else 0


def in_step(actors: Sequence[Actor]) -> list[int]:
    """Start frames that begin everybody at a left stride: people in step, so that a
    partner's legs follow from the leader's (two walkers at a random phase to each other
    teach a flow the average of all phases: legs that barely move). Everybody is cut alike,
    so a run's start from rest is skipped by all. A clip that appears again (the leader's
    own, where no other clip has its pace) starts a stride later each time, so that it is
    not a copy; it keeps its heading and curve, where a mirrored copy would curve away."""
    return [stride_start(a.joints, sum(b is a for b in actors[:i])) for i, a in enumerate(actors)]
