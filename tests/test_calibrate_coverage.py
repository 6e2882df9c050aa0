"""research/calibrate_coverage.py: the threshold's choice and the fresh lists' rates."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

cal = load_script("calibrate_coverage")


def test_the_threshold_flags_at_most_a_tenth_of_the_calibration_paraphrases():
    known = np.linspace(0.6, 1.0, 20)  # two lie below 0.64
    unseen = np.linspace(0.3, 0.7, 20)
    t = cal.choose(known, unseen)
    assert (known < t).mean() <= 0.10
    higher = [c for c in np.round(np.concatenate([known, unseen]), 4) if c > t]
    assert all((known < c).mean() > 0.10 for c in higher)  # the highest that does
    r = cal.rates(known, unseen, t)
    assert r["paraphrases_flagged"] == 0.1 and r["unseen_flagged"] > 0.8


@pytest.mark.parametrize(("k", "n", "lo", "hi"), [(9, 92, 0.0523, 0.1756), (0, 10, 0.0, 0.2775),
                                                  (10, 10, 0.7225, 1.0)])  # fmt: skip
def test_wilson_intervals_match_the_textbook_values(k, n, lo, hi):
    a, b = cal.wilson(k, n)
    assert a == pytest.approx(lo, abs=1e-4) and b == pytest.approx(hi, abs=1e-4)
    assert a <= k / n <= b


def test_the_fresh_lists_are_read_from_the_models_own_verdicts():
    known = [{"known": True}] * 9 + [{"known": False}]
    unseen = [{"known": False}] * 4 + [{"known": True}]
    r = cal.test_report(known, unseen)
    assert r["paraphrases_flagged"] == 0.1 and r["unseen_flagged"] == 0.8
    assert r["precision"] == 0.8  # 4 of the 5 flagged prompts are unseen
