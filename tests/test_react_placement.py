"""research/react_placement.py: the per-frame gap on motions whose answer is known."""

from __future__ import annotations

import numpy as np

from conftest import load_script


def test_gaps_are_measured_on_the_floor_plane_per_frame():
    rp = load_script("react_placement")
    t = np.arange(31) / 30.0
    a = np.zeros((31, 22, 3))
    a[:, :, 1] = 1.0  # height never counts
    b = a.copy()
    b[:, :, 0] = 3.0  # 3 m to the side ...
    b[:, 0, 2] = 1.2 * t  # ... the pelvis walking forward at 1.2 m/s
    b[:, 1:, 1] = 5.0  # other joints than the pelvis never count
    assert np.allclose(rp.pelvis_gaps(a, a), 0.0)
    gaps = rp.pelvis_gaps(a, b)
    assert gaps.shape == (31,)
    assert np.allclose(gaps, np.hypot(3.0, 1.2 * t))
    assert np.isclose(gaps[0], 3.0)
