"""research/group_positions.py: where people 2..N stand relative to person 1."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

gp = load_script("group_positions")


def _body(x: float, z: float, frames: int = 5) -> np.ndarray:
    """A standing stick body (T, 22, 3) at (x, z) facing +Z (shoulders and hips along x)."""
    from umf.skeleton import JOINT_NAMES

    j = np.zeros((frames, 22, 3))
    j[..., 1] = np.linspace(0.0, 1.7, 22)
    for name, dx in (("l_hip", 0.1), ("r_hip", -0.1), ("l_shoulder", 0.2),
                     ("r_shoulder", -0.2)):  # fmt: skip
        j[:, JOINT_NAMES.index(name), 0] = dx
    j[..., 0] += x
    j[..., 2] += z
    return j


def test_a_file_and_a_row():
    """Person 2 two metres behind, person 3 one metre to the left: +x is the left of a
    person facing +Z."""
    scene = np.stack([_body(0, 0), _body(0, -2.0), _body(1.0, 0)])
    (l0, l1, f0, f1), (m0, m1, g0, g1) = gp.positions(scene)
    assert (l0, l1) == pytest.approx((0, 0), abs=1e-6)
    assert (f0, f1) == pytest.approx((-2.0, -2.0), abs=1e-6)
    assert (m0, m1, g0, g1) == pytest.approx((1.0, 1.0, 0.0, 0.0), abs=1e-6)
