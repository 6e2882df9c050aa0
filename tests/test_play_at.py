"""A partner played at the leader's pace (``sflow.warm_play``) and a person 3 who keeps off
person 2's side (``sflow.warm_apart``): the motion maths, on a synthetic gait and a real walk."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from umf.data import extension as E
from umf.representation import assemble_features, features_to_joints, joints_to_rot6d
from umf.warm_start import play_at, taken_sides

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


def test_taken_sides_sends_person_3_to_the_free_side():
    stand = torch.tensor([1.0, 1.0, -1.0, 0.0, 1.0])
    others = torch.tensor([
        [[0.9, 0.0]],  # person 2 on the left: person 3 goes right
        [[-0.9, 0.1]],  # person 2 on the right: the left is free, stays
        [[-0.1, 2.0]],  # person 2 straight ahead (within the side margin): stays
        [[0.9, 0.0]],  # no side asked: none given
        [[0.9, 0.0]],  # (row 5 has person 3 on the left too, below)
    ])  # fmt: skip
    assert taken_sides(stand, others).tolist() == [-1.0, 1.0, -1.0, 0.0, -1.0]
    both = torch.tensor([[[0.9, 0.0], [-0.9, 0.0]]])  # both sides taken: as it was
    assert taken_sides(torch.tensor([1.0]), both).tolist() == [1.0]
