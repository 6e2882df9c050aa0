"""research/runner_turns.py: how far runners turn, and how fast partners drift apart."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

runner_turns = load_script("runner_turns")


def _pair(drift: float, frames: int = 31) -> np.ndarray:
    """Two bodies (2, T, 22, 3) running along +Z, person 2 starting 1 m to the left and
    moving ``drift`` m further left over the crop."""
    t = np.linspace(0.0, 1.0, frames)
    j = np.zeros((2, frames, 22, 3))
    j[..., 2] = 2.5 * t[None, :, None]
    j[1, ..., 0] = 1.0 + drift * t[:, None]
    return j


@pytest.mark.parametrize("drift", [0.0, 0.3, -0.6])
def test_sideways_drift_is_the_change_of_offset_across_the_leaders_chord(drift):
    # 31 frames at 30 fps: one second
    assert runner_turns.sideways_drift(_pair(drift), 30.0) == pytest.approx(abs(drift))


def test_a_turn_to_the_right_is_positive():
    """Floor paths (x, z), +x the left of someone walking along +z: a quarter turn to the
    left after the first chord reads -90, to the right +90 (the docstring said + to the
    left until this test)."""
    t = np.linspace(0.0, 1.0, 2 * runner_turns.HALF + 1)
    left = np.stack([np.where(t < 0.5, 0.0, t - 0.5), np.minimum(t, 0.5)], -1)
    assert runner_turns.turn_deg(left) == pytest.approx(-90.0)
    right = left * np.array([-1.0, 1.0])
    assert runner_turns.turn_deg(right) == pytest.approx(90.0)


@pytest.mark.parametrize("frames", [79, 120, 151])
def test_turn_halves_reads_a_known_turn_at_any_length(frames):
    """A path straight along +z for its first half, then turned 30 degrees towards -x (to
    the right of someone facing +z, whose left is +x): +30, whatever its length; mirrored,
    -30; at 4 s (120 frames) the same as turn_deg's 2-second chords."""
    half = frames // 2
    right = np.radians(30.0)
    first = np.stack([np.zeros(half + 1), np.linspace(0.0, 1.0, half + 1)], -1)
    way = np.array([-np.sin(right), np.cos(right)])
    second = first[-1] + np.linspace(0.0, 1.0, frames - half)[1:, None] * way
    path = np.concatenate([first, second])
    assert len(path) == frames
    assert runner_turns.turn_halves(path) == pytest.approx(30.0, abs=1e-6)
    assert runner_turns.turn_halves(path * np.array([-1.0, 1.0])) == pytest.approx(-30.0, abs=1e-6)
    if frames == 120:
        assert runner_turns.turn_deg(path) == pytest.approx(30.0, abs=1e-6)
