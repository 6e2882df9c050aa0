"""research/partner_pace.py: the followers' pace at each step of the warm start."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

partner_pace = load_script("partner_pace")


def test_chord_speed_is_start_to_end_floor_speed(actors):
    walker = next(a for a in actors if "walk" in a.id).joints[:31]
    moved = walker.copy()
    moved[..., 2] += np.linspace(0.0, 1.5, 31)[:, None]  # 1.5 m more along z in 1 s
    moved[..., 1] += 5.0  # height does not count
    speed = partner_pace.chord_speed(np.stack([walker, moved]), 30.0)
    p = walker[:, 0][:, [0, 2]]
    want = np.linalg.norm(p[-1] - p[0]) * 30.0 / 30
    assert speed[0] == pytest.approx(want, abs=1e-5)
    assert speed[1] == pytest.approx(np.linalg.norm(p[-1] - p[0] + [0.0, 1.5]) * 30 / 30, abs=1e-5)
    assert set(partner_pace.PROMPTS) == {2, 3}
