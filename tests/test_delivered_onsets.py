"""research/delivered_onsets.py: whole-body and upper-body onsets of the same people, raw
and delivered (why delivered answers seem to start at other frames)."""

from __future__ import annotations

import numpy as np

from conftest import load_script

LEGS = [1, 2, 4, 5, 7, 8, 10, 11]  # hips, knees, ankles, feet (SMPL-22)


def person(jitter: float, raise_at: int, frames: int = 90, seed: int = 0) -> np.ndarray:
    """A standing body (T, 22, 3) whose legs shimmer by ``jitter`` m frame to frame and whose
    wrists and elbows rise 0.6 m from frame ``raise_at`` over 20 frames."""
    rng = np.random.default_rng(seed)
    body = np.repeat((rng.uniform(-0.2, 0.2, (22, 3)) + np.array([0.0, 1.0, 0.0]))[None], frames, 0)
    body[:, LEGS] += rng.normal(0.0, jitter, (frames, len(LEGS), 3))
    lift = np.clip((np.arange(frames) - raise_at) / 20.0, 0.0, 1.0) * 0.6
    body[:, [18, 19, 20, 21], 1] += lift[:, None]
    return body


def test_leg_shimmer_moves_the_whole_body_onset_not_the_upper_bodys():
    """The same raise of the arms, with shimmering legs (raw) and still ones (delivered):
    the whole-body onset moves by frames, the upper body's does not."""
    do = load_script("delivered_onsets")
    raw = np.stack([person(0.0, 10), person(0.01, 40, seed=1)])
    delivered = np.stack([person(0.0, 10), person(0.0, 40, seed=1)])
    (wr, ur), (wd, ud) = do.onsets(raw), do.onsets(delivered)
    assert ur == ud and abs(ud[1] - 40) <= 4  # the arms rise at 40 either way
    assert wr[1] < wd[1] - 5  # the shimmer's share of the motion: a tenth comes early


def test_compare_counts_starts_after_checks_on_both_readings():
    do = load_script("delivered_onsets")
    record = {"constraints": [{"type": "starts_after", "a": 0, "b": 1, "min_frames": 8},
                              {"type": "faces", "a": 1, "b": 0}]}  # fmt: skip
    raw = np.stack([person(0.0, 10), person(0.01, 40, seed=1)])
    delivered = np.stack([person(0.0, 10), person(0.0, 40, seed=1)])
    early = np.stack([person(0.0, 10), person(0.0, 12, seed=1)])  # answers 2 frames late
    out = do.compare([record, record], [raw, early], [delivered, early])
    assert out["people"] == 2 and out["checks"] == 2
    assert out["passing"]["delivered, upper body"] == 1  # the late answer only
    assert out["passing"]["raw, upper body"] == 1
    assert out["shift_upper"]["max_abs"] == 0
    assert out["shift_whole"]["max_abs"] > 5
    assert do.starts_after([10, 18], record["constraints"]) == [True]
    assert do.starts_after([10, 17], record["constraints"]) == [False]
