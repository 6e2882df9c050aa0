"""research/turning_runners.py: where person 2 ends along person 1's chord."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

tr = load_script("turning_runners")


@pytest.mark.parametrize(("lead", "ahead"), [(0.0, 0.0), (-1.2, -1.2), (0.5, 0.5)])
def test_ends_ahead_is_along_person_1s_chord_whatever_the_side(lead, ahead):
    """Person 1 runs 10 m along +z; person 2 ends 0.8 m to one side and ``lead`` m further
    along, wherever it started: only the component along the chord counts."""
    t = np.linspace(0.0, 1.0, 31)[:, None]
    joints = np.zeros((2, 31, 22, 3))
    joints[0, :, :, 2] = 10.0 * t
    joints[1, :, :, 0] = -0.8
    joints[1, :, :, 2] = (10.0 + lead) * t - 2.0 * (1 - t)
    paths = tr.floor_paths(joints)
    assert paths.shape == (2, 31, 2)
    assert tr.ends_ahead(paths) == pytest.approx([ahead])
    turned = paths @ np.array([[0.0, 1.0], [-1.0, 0.0]])  # the whole scene turned 90 degrees
    assert tr.ends_ahead(turned) == pytest.approx([ahead])
