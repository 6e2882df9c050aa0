"""A partner carried along the leader's path (umf.path_follow): the path maths and the carry."""

from __future__ import annotations

import numpy as np
import pytest

from umf.path_follow import arc_length, centred_mean, follow_path, path_turn, path_yaw, turn

FPS = 30.0
T = 121


def _body() -> np.ndarray:
    body = np.random.default_rng(0).normal(size=(22, 3)) * 0.3
    body[0] = 0.0
    body[:, 1] += 1.0
    return body


def _person(path: np.ndarray, yaw: np.ndarray | None = None, clock: np.ndarray | None = None):
    """Joints (T, 22, 3) of a rigid body whose pelvis follows the floor ``path`` (T, 2),
    turned to ``yaw`` (default: the path's tangent); joint 21's height tells ``clock``."""
    yaw = path_yaw(path) if yaw is None else yaw
    j = np.repeat(_body()[None], len(path), axis=0)
    j[..., [0, 2]] = path[:, None] + turn(j[..., [0, 2]], yaw[:, None])
    if clock is not None:
        j[:, 21, 1] = clock
    return j


def _straight(x0: float, speed: float, sway: float = 0.0) -> np.ndarray:
    t = np.arange(T) / FPS
    return np.stack([x0 + sway * np.sin(2 * np.pi * t), speed * t], axis=-1)


def _circle(radius: float, speed: float) -> np.ndarray:
    """A path turning left (towards +X) from the origin, heading +Z."""
    a = speed * np.arange(T) / FPS / radius
    return np.stack([radius - radius * np.cos(a), radius * np.sin(a)], axis=-1)


def test_turn_path_yaw_and_arc_length_agree_on_a_circle():
    np.testing.assert_allclose(turn(np.array([0.0, 1.0]), np.pi / 2), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(turn(np.array([1.0, 0.0]), np.pi / 2), [0.0, -1.0], atol=1e-12)
    path = _circle(8.0, 3.0)
    a = 3.0 * np.arange(T) / FPS / 8.0
    np.testing.assert_allclose(path_yaw(path)[1:-1], a[1:-1], atol=1e-3)
    np.testing.assert_allclose(arc_length(path)[-1], 3.0 * (T - 1) / FPS, rtol=1e-3)


def test_smoothing_keeps_a_steady_line_and_takes_out_a_strides_sway():
    line = _straight(0.3, 1.4)
    np.testing.assert_allclose(centred_mean(line), line, atol=1e-12)
    swaying = _straight(0.3, 1.4, sway=0.05)
    inner = slice(20, -20)
    assert np.abs(centred_mean(swaying)[inner, 0] - 0.3).max() < 0.05 * 0.1


def test_a_partner_beside_a_steady_leader_at_their_pace_is_left_as_they_are():
    leader, partner = _person(_straight(0.0, 1.3, 0.03)), _person(_straight(-0.8, 1.3, 0.03))
    # within their 3 cm sway, which the smoothing's narrowed windows see at the ends
    np.testing.assert_allclose(follow_path(partner, leader), partner, atol=0.025)
    still = _person(_straight(-0.8, 1.3))
    np.testing.assert_allclose(follow_path(still, _person(_straight(0.0, 1.3))), still,
                               atol=1e-6)  # fmt: skip


@pytest.mark.parametrize("side", [-0.8, 0.8])
def test_a_straight_partner_turns_with_a_curving_leader_and_keeps_beside(side):
    leader = _person(_circle(6.0, 3.0))
    partner = _person(_straight(side, 3.0))
    out = follow_path(partner, leader)
    rel = out[:, 0, [0, 2]] - leader[:, 0, [0, 2]]
    heading = path_yaw(leader[:, 0, [0, 2]])
    forward = (rel * np.stack([np.sin(heading), np.cos(heading)], -1)).sum(-1)
    across = np.linalg.norm(rel, axis=-1)
    # beside them all the way (a straight partner ends 3.5 m behind along the leader's end
    # heading); the smoothing of a stride's sway pulls a 6 m circle 7 cm in
    assert np.abs(forward).max() < 0.05 and np.abs(across - abs(side)).max() < 0.08
    straight = partner[-1, 0, [0, 2]] - leader[-1, 0, [0, 2]]
    assert straight @ np.array([np.sin(heading[-1]), np.cos(heading[-1])]) < -2.0
    # the body turns as the path does: the hips' line keeps square to the leader's heading
    hips = out[:, 2, [0, 2]] - out[:, 1, [0, 2]]
    lead_hips = leader[:, 2, [0, 2]] - leader[:, 1, [0, 2]]
    cos = (
        (hips * lead_hips).sum(-1)
        / np.linalg.norm(hips, axis=-1)
        / np.linalg.norm(lead_hips, axis=-1)
    )
    assert cos[10:-10].min() > 0.99
    np.testing.assert_allclose(out[..., 1], partner[..., 1])  # heights untouched


def test_the_partner_is_played_as_fast_as_its_new_path_asks():
    """Its own frames are taken where its stride covered as much ground: beside a leader at
    0.8 of its pace, frame t shows its own frame 0.8 t (joint 21's height tells which)."""
    clock = np.arange(T, dtype=np.float64) / 100
    partner = _person(_straight(-0.8, 1.5), clock=clock)
    leader = _person(_straight(0.0, 1.2))
    out = follow_path(partner, leader)
    np.testing.assert_allclose(out[:, 21, 1], 0.8 * clock, atol=2e-3)
    np.testing.assert_allclose(out[-1, 0, 2], leader[-1, 0, 2], atol=0.02)


def test_a_leader_who_slows_down_is_kept_up_with():
    t = np.arange(T) / FPS
    z = np.where(t < 2, 3.5 * t, 7.0 + 2.5 * (t - 2))  # 3.5 m/s, then 2.5
    leader = _person(np.stack([np.zeros(T), z], -1), yaw=np.zeros(T))
    partner = _person(_straight(0.9, 3.0))
    out = follow_path(partner, leader)
    gap = out[:, 0, 2] - leader[:, 0, 2]
    assert np.abs(gap).max() < 0.15  # a steady 3 m/s partner drifts 0.5 m either way


def test_someone_standing_still_is_neither_carried_nor_followed():
    still = _person(np.tile([0.7, 0.0], (T, 1)), yaw=np.zeros(T))
    leader = _person(_circle(5.0, 2.0))
    np.testing.assert_array_equal(follow_path(still, leader), still)
    walker = _person(_straight(0.8, 1.2))
    np.testing.assert_array_equal(follow_path(walker, still), walker)  # nobody to follow


def test_path_turn_reads_how_far_a_path_turns_either_way():
    left = _person(_circle(6.0, 3.0))  # 3 m/s for 4 s on a 6 m circle: 2 rad
    assert path_turn(left) == pytest.approx(np.degrees(2.0), abs=2.0)
    right = left.copy()
    right[..., 0] *= -1
    assert path_turn(right) == pytest.approx(path_turn(left), abs=1e-9)
    assert path_turn(_person(_straight(0.0, 1.3, sway=0.05))) < 2.0


def test_a_leader_of_another_length_is_refused():
    with pytest.raises(ValueError, match="frames against the leader"):
        follow_path(_person(_straight(0.8, 1.0)), _person(_straight(0.0, 1.0))[:-1])
