"""A partner played at the leader's pace (``sflow.warm_play``) and a person 3 who keeps off
person 2's side (``sflow.warm_apart``): the motion maths, on a synthetic gait and a real walk."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from umf.clearance import beyond, turned_free
from umf.data import extension as E
from umf.representation import assemble_features, features_to_joints, joints_to_rot6d
from umf.warm_start import play_at

PERIOD = 24  # frames of the synthetic gait's cycle


def gait(frames: int = 90, speed: float = 0.05) -> np.ndarray:
    """A body (T, 22, 3) travelling along +Z at ``speed`` m/frame, its joints swinging with
    period ``PERIOD``: a steady gait whose last cycle repeats exactly."""
    rng = np.random.default_rng(0)
    pose = rng.normal(0.0, 0.3, (22, 3)) + np.array([0.0, 1.0, 0.0])
    pose[0] = (0.0, 1.0, 0.0)
    swing = rng.normal(0.0, 0.05, (22, 3))
    swing[0] = 0.0
    t = np.arange(frames)[:, None, None]
    joints = pose + np.sin(2 * np.pi * t / PERIOD) * swing
    joints[..., 2] += speed * t[..., 0]
    return joints


def test_played_at_rate_1_is_the_motion_itself():
    j = gait()
    np.testing.assert_allclose(E.played_at(j, 1.0, 60), j[:60], atol=1e-12)


@pytest.mark.parametrize("rate", [0.8, 1.1, 1.25])
def test_played_at_travels_rate_times_as_fast_and_carries_the_gait_on(rate):
    j = gait(frames=90, speed=0.05)
    out = E.played_at(j, rate, 90)  # a quarter faster needs 112 frames: the cycle repeats
    assert out.shape == (90, 22, 3)
    pelvis = out[:, 0, 2]
    np.testing.assert_allclose(np.diff(pelvis), 0.05 * rate, atol=1e-9)
    # the pose relative to the pelvis is the gait's at time i * rate, past the end too
    want = gait(frames=200, speed=0.05)
    times = np.arange(90) * rate
    lo = np.floor(times).astype(int)
    w = (times - lo)[:, None, None]
    expected = want[lo] * (1 - w) + want[lo + 1] * w
    np.testing.assert_allclose(out - out[:, :1], expected - expected[:, :1], atol=1e-9)


def test_played_at_clamps_the_rate():
    j = gait()
    np.testing.assert_allclose(E.played_at(j, 3.0, 60), E.played_at(j, E.PLAY_FASTEST, 60))
    np.testing.assert_allclose(E.played_at(j, 0.1, 60), E.played_at(j, E.PLAY_SLOWEST, 60))


def test_play_at_plays_features_and_keeps_the_first_frame(real_joints):
    """Features of a real walk played 1.2 times as fast: the same first frame, the pelvis
    1.2 times as far, the features those of the played joints (rotations recovered)."""
    joints = real_joints[:121].float()
    feats = assemble_features(joints, joints_to_rot6d(joints))[None]  # (1, 120, 262)
    same = play_at(feats, torch.tensor([1.0]))
    torch.testing.assert_close(features_to_joints(same), features_to_joints(feats), atol=1e-5,
                               rtol=0)  # fmt: skip
    fast = play_at(feats, torch.tensor([1.2]))
    assert fast.shape == feats.shape
    p0, p1 = (features_to_joints(f)[0, :, 0, [0, 2]] for f in (feats, fast))
    torch.testing.assert_close(p1[0], p0[0])
    ratio = float((p1[-1] - p1[0]).norm() / (p0[-1] - p0[0]).norm())
    assert abs(ratio - 1.2) < 0.05, ratio


def _standing(x: float, z: float, frames: int = 10) -> torch.Tensor:
    """Features (frames, 262) of a still body whose pelvis starts at (x, z) on the floor."""
    joints = torch.zeros(frames + 1, 22, 3)
    joints[..., 1] = torch.linspace(0.0, 1.6, 22)
    joints[..., 0] += x
    joints[..., 2] += z + torch.linspace(0.0, 0.3, 22)  # a body, not a point
    return assemble_features(joints, torch.zeros(frames + 1, 21, 6))


def test_beyond_puts_person_3_as_far_past_person_2_as_2_is_past_person_1():
    """A row starting on someone's spot moves by that person's start, again while it lands
    on someone (a line of four); a row on nobody's spot, or with nobody (NaN), stays."""
    rows = torch.stack([_standing(0.9, 0.0), _standing(0.1, -2.0), _standing(-0.9, 0.1),
                        _standing(0.9, 0.0), _standing(0.9, 0.0)])  # fmt: skip
    others = torch.tensor([
        [[0.95, 0.05], [-5.0, -5.0]],  # person 2 on the left: beyond, at 1.85
        [[0.0, -2.1], [0.0, -4.0]],  # single file: behind 2 is 3's spot, so one more step
        [[0.95, 0.05], [-5.0, -5.0]],  # this row is on the right: nobody there
        [[0.9, 0.0], [1.8, 0.0]],  # a line of four: beyond 2 is 3's spot, beyond 3 is free
        [[float("nan"), float("nan")], [float("nan"), float("nan")]],  # nobody
    ])  # fmt: skip
    start = features_to_joints(beyond(rows, others)[:, :1])[:, 0, 0][:, [0, 2]]
    want = torch.tensor([[1.85, 0.05], [0.1, -6.2], [-0.9, 0.1], [2.7, 0.0], [0.9, 0.0]])
    torch.testing.assert_close(start, want, atol=1e-5, rtol=0)
    moved = beyond(rows, others)
    torch.testing.assert_close(moved[:, :, 66:], rows[:, :, 66:])  # velocities and the rest


def test_turned_free_turns_an_answer_about_person_1_to_a_free_bearing():
    """A row facing person 1 from person 2's spot is turned about the origin by the smallest
    bearing that clears everybody by ``clear`` (by default ``AROUND``): the same distance
    from person 1; a row already clear stays."""
    import math

    from umf.clearance import AROUND

    rows = torch.stack([_standing(0.0, 2.4), _standing(3.0, 3.0)])
    others = torch.tensor([[[0.05, 2.45]], [[0.05, 2.45]]])
    out, turned = turned_free(rows, others)
    assert turned.tolist() == [True, False]
    start = features_to_joints(out[:, :1])[:, 0, 0][:, [0, 2]]
    assert float(start[0].norm()) == pytest.approx(2.4, abs=1e-5)  # as far from person 1
    assert float((start[0] - others[0, 0]).norm()) >= AROUND
    bearing = math.degrees(math.atan2(float(start[0, 0]), float(start[0, 1])))
    assert abs(bearing) == pytest.approx(40.0, abs=1e-3)  # 20 is not enough at 2.4 m
    torch.testing.assert_close(out[1:], rows[1:])
    # a smaller clearance is met at the first bearing
    near, _ = turned_free(rows[:1], others[:1], clear=0.8)
    first = features_to_joints(near[:, :1])[0, 0, 0, [0, 2]]
    assert abs(math.degrees(math.atan2(float(first[0]), float(first[1])))) == pytest.approx(20.0)


def test_clear_of_moves_a_partner_sideways_until_no_joint_is_too_near():
    """A partner 0.3 m to the leader's left (or right) moves out until every joint is 0.4 m
    from the leader's, a little past; one already clear, or straight behind, stays."""
    from umf.clearance import PLAY_CLEAR, clear_of

    leader = torch.stack([_standing(0.0, 0.0)] * 4)
    rows = torch.stack([_standing(0.3, 0.0), _standing(-0.3, 0.0), _standing(1.0, 0.0),
                        _standing(0.0, -0.3)])  # fmt: skip
    out = clear_of(rows, leader)
    x = features_to_joints(out[:, :1])[:, 0, 0, 0]
    assert PLAY_CLEAR <= float(x[0]) <= PLAY_CLEAR + 0.05
    assert -PLAY_CLEAR - 0.05 <= float(x[1]) <= -PLAY_CLEAR
    torch.testing.assert_close(out[2:], rows[2:])
    gap = features_to_joints(out[:2])[:, :, :, None] - features_to_joints(leader[:2])[:, :, None]
    assert float(gap.norm(dim=-1).min()) >= PLAY_CLEAR
    # never pushed to start farther out than PLAY_FARTHEST, clear or not
    from umf.clearance import PLAY_FARTHEST

    wide = clear_of(_standing(1.2, 0.0)[None], _standing(1.0, 0.0)[None])
    assert float(features_to_joints(wide[:, :1])[0, 0, 0, 0]) == pytest.approx(PLAY_FARTHEST)
