"""research/single_file_order.py: where people of a single file start, and whether in order."""

from __future__ import annotations

import numpy as np

from conftest import load_script

single_file_order = load_script("single_file_order")


def _file(zs: list[float], frames: int = 11) -> np.ndarray:
    """Bodies (N, T, 22, 3) walking along +Z, person k starting ``zs[k]`` m along it."""
    t = np.linspace(0.0, 1.0, frames)
    j = np.zeros((len(zs), frames, 22, 3))
    j[..., 1] = np.linspace(0.0, 1.6, 22)
    j[..., 2] = np.asarray(zs)[:, None, None] + 1.2 * t[None, :, None]
    j[:, :, [1, 16], 0] = 0.15  # left hip and shoulder (SMPL-22), facing +Z: left is +X
    j[:, :, [2, 17], 0] = -0.15
    return j


def test_ahead_of_leader_reads_the_first_frame_along_person_1s_heading():
    ahead = single_file_order.ahead_of_leader(_file([0.0, -2.0, -4.1]))
    np.testing.assert_allclose(ahead, [-2.0, -4.1], atol=1e-6)


def test_in_order_needs_each_behind_the_one_before():
    assert single_file_order.in_order([-2.0, -4.0, -6.0])
    assert not single_file_order.in_order([-2.0, -1.2, -3.1])  # person 3 ahead of person 2
    assert not single_file_order.in_order([0.5, -1.0])  # person 2 ahead of person 1
    assert not single_file_order.in_order([])


def test_tracks_start_person_1_at_the_origin_heading_up():
    """Person 1 walks up the page from the origin; a person 1 m to their left is drawn at
    x = -1 (their left on the left), 2 m behind at y = -2."""
    j = _file([0.0, -2.0])
    j[1, :, :, 0] += 1.0  # person 2 one metre to person 1's left (+X when facing +Z)
    (x1, y1), (x2, y2) = single_file_order.tracks(j)
    np.testing.assert_allclose([x1[0], y1[0], y1[-1]], [0.0, 0.0, 1.2], atol=1e-6)
    np.testing.assert_allclose([x2[0], y2[0]], [-1.0, -2.0], atol=1e-6)
