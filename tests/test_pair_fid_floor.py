"""research/pair_fid_floor.py: moving a person to another's start is one rigid floor motion."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_script
from umf.representation import (
    POS,
    assemble_features,
    features_to_joints,
    heading_angle,
    joints_to_rot6d,
    place_features,
)


def test_start_as_puts_the_first_frame_on_the_reference_and_keeps_the_pose(real_joints):
    pf = load_script("pair_fid_floor")
    j = real_joints[:40].float()
    walk = assemble_features(j, joints_to_rot6d(j))  # (39, 262), walking away from its start
    ref = place_features(walk, 2.0, 1.5, -0.7)[5:]  # turned, moved, and later in the walk
    moved = torch.from_numpy(pf.start_as(walk.numpy(), ref.numpy()))
    m0, r0 = features_to_joints(moved[0]), features_to_joints(ref[0])
    assert torch.allclose(m0[0, [0, 2]], r0[0, [0, 2]], atol=1e-4)  # pelvis on the floor
    assert torch.isclose(heading_angle(m0), heading_angle(r0), atol=1e-4)
    assert torch.allclose(m0[0, 1], features_to_joints(walk[0])[0, 1], atol=1e-5)  # height kept
    # the same walk, rigidly: every pairwise joint distance over time unchanged
    a = moved[..., POS].reshape(-1, 3).double()
    b = walk[..., POS].reshape(-1, 3).double()
    assert torch.allclose(torch.cdist(a, a), torch.cdist(b, b), atol=1e-4)
    assert torch.allclose(moved[..., POS.stop + 66 :], walk[..., POS.stop + 66 :], atol=1e-6)
    assert not torch.allclose(moved[..., POS], walk[..., POS], atol=0.1)


def test_pair_motion_stats_tells_a_glide_from_a_walk(real_joints):
    pm = load_script("pair_motion_stats")
    walk = real_joints[:90].numpy()
    glide = np.repeat(walk[:1], 90, axis=0)  # the first pose, carried along the walk's path
    glide = glide + (walk[:, :1] - walk[:1, :1]) * np.array([1.0, 0.0, 1.0])
    w, g = pm.row([walk], 30.0), pm.row([glide], 30.0)
    speed, ankle = pm.STATS.index("pelvis_speed"), pm.STATS.index("ankle_energy")
    assert g[speed] == pytest.approx(w[speed], rel=0.05) and w[speed] > 0.5
    assert g[ankle] < 0.05 < 0.5 < w[ankle]  # the same travel, still legs
    steady = np.linspace(0, 1, 30)[:, None, None] * np.ones((30, 22, 3))
    assert pm.row([steady], 30.0)[-1] == pytest.approx(0.0, abs=1e-9)  # no acceleration
    assert pm.row([walk], 30.0)[-1] > 0.5
