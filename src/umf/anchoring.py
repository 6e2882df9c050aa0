"""Planted feet stay put: where a generated foot slides on the floor, move the body instead.

A decoded person often glides: the contact labels say a foot is on the floor while the
whole body, that foot included, keeps travelling (about 1 m/s in the bundled model's
walks, and a standing person drifts). Pinning the foot alone (:mod:`umf.kinematics`) cannot
fix that, since a leg reaches only a few centimetres from where the pelvis is. This
module corrects the body's floor path instead, the usual foot-skate clean-up of animation
pipelines: at every step t -> t+1 during which a foot is planted, the whole person is
moved back by that foot's horizontal slide, so the foot stands still and the body travels
only as far as its legs carry it. Heights and the pose are untouched; only a per-frame
horizontal translation of the person changes, and it accumulates (a glider ends nearer to
where it started).

A foot joint (ankle or toe) is planted where its contact label is on and it is low enough
(InterGen's contact heights above the floor, as :mod:`umf.kinematics` pins it); a foot is
planted when one of its two joints is (it pivots about the heel or the toes), and its slide
is that of the slower planted joint. With both feet planted the slower foot is the one
that stands. On real motion the correction is small but not zero (the contact labels are
InterGen's, which call a foot planted below about 1 m/s): the walks and the run of the
repository's Bandai sample keep at least 93 % of their travel (`tests/test_anchoring.py`).
The slides are smoothed over a few frames before they are summed: switched on and off
frame by frame, the correction would jolt the body at every contact change; smoothed, the
delivered scenes' jerk stays below the raw output's (356 against 383 m/s³ for the test
pairs in the report below).

Measured on the bundled model (`umf eval`, all 300 test pairs and 200 groups, after
separation and the kinematic fit: `results/umf-small-bandai-20261126c/protocol`):
foot skating ratio 0.40 -> 0.10 for pairs (real 0.05), 0.42 -> 0.09 for groups (real
0.04); a walk keeps 95 % of its raw speed, a run 90 % (now below the real range); bowing
and hand-raising people drift half as much across the floor.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from umf.kinematics import planted_feet
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT

FEET = (FOOT_LEFT, FOOT_RIGHT)  # (ankle, toe) joints; contact slots 0, 1 and 2, 3
SMOOTH = 1.5  # frames: Gaussian sigma over which the slides are spread (0: none)


def foot_slides(joints: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(T-1, 2) horizontal (X, Z) slide of the standing foot per step; zero where none.

    ``planted`` (T, 2 feet, 2 joints: ankle, toe) is :func:`umf.kinematics.planted_feet`
    per foot. A step counts a joint as planted when it is planted at both ends. Among the planted
    joints of both feet, the one that moves least stands; its displacement is the slide.
    """
    feet = joints[:, [list(FEET[0]), list(FEET[1])]][..., [0, 2]]  # (T, 2, 2, 2)
    step = np.diff(feet, axis=0)  # (T-1, 2 feet, 2 joints, XZ)
    both = planted[1:] & planted[:-1]  # (T-1, 2, 2)
    dist = np.where(both, np.linalg.norm(step, axis=-1), np.inf).reshape(len(step), 4)
    best = dist.argmin(axis=1)
    slide = step.reshape(len(step), 4, 2)[np.arange(len(step)), best]
    return np.where(np.isfinite(dist.min(axis=1))[:, None], slide, 0.0)


def anchor_feet(
    joints: np.ndarray, contacts: np.ndarray, floor: float = 0.0, smooth: float = SMOOTH
) -> tuple[np.ndarray, np.ndarray]:
    """One person's joints (T, 22, 3) moved so planted feet stay where they landed.

    Returns the corrected joints and the per-frame horizontal translation (T, 3) that was
    added (zero at frame 0, Y always zero): the running sum of minus the standing foot's
    slide, smoothed over ``smooth`` frames.
    """
    j = np.asarray(joints, dtype=np.float64)
    planted = planted_feet(j, np.asarray(contacts), floor).reshape(len(j), 2, 2)
    slides = foot_slides(j, planted)
    if smooth > 0 and len(slides) > 1:
        slides = gaussian_filter1d(slides, smooth, axis=0, mode="nearest")
    shift = np.zeros((j.shape[0], 3))
    shift[1:, [0, 2]] = -np.cumsum(slides, axis=0)
    return (j + shift[:, None, :]).astype(np.asarray(joints).dtype), shift


def anchor_people(
    joints: np.ndarray,
    contacts: np.ndarray,
    floor: float = 0.0,
    clean: bool | list[bool] = True,
    together: int = 0,
) -> np.ndarray:
    """:func:`anchor_feet` for a scene's people (N, T, 22, 3) with contacts (N, T, 4);
    people whose ``clean`` flag is False (a user's own motion) are returned as they are.

    ``together`` >= 2: the first ``together`` people are held together by the prompt (a
    salsa couple, hand in hand) and move as one, each by the mean of their corrections, so
    where they stand to each other is the decoder's; everyone else, and a couple beside a
    user's own motion, is anchored one by one. Anchored one by one, a generated couple that
    held hands in 58 % of its frames (median of seeds 8-23, warm_take 0.8) did in 48 %
    (results/umf-small-bandai-20261213; a throw-away measurement during the change: the
    pipeline no longer anchors a couple one by one)."""
    flags = [clean] * len(joints) if isinstance(clean, bool) else list(clean)
    out = [anchor_feet(p, c, floor) if use else (np.asarray(p), None)
           for p, c, use in zip(joints, contacts, flags, strict=True)]  # fmt: skip
    held = range(min(together, len(joints)))
    if together >= 2 and all(flags[k] for k in held):
        shift = np.mean([out[k][1] for k in held], axis=0)
        base = np.asarray(joints[0]).dtype
        for k in held:
            out[k] = ((np.asarray(joints[k], dtype=np.float64) + shift[:, None, :]).astype(base),
                      shift)  # fmt: skip
    return np.stack([p for p, _ in out])
