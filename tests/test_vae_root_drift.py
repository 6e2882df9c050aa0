"""research/vae_root_drift.py: the drift measures of one person's features."""

from __future__ import annotations

import numpy as np
import torch

from conftest import load_script
from umf.representation import joints_to_features


def _person(offsets: np.ndarray) -> np.ndarray:
    """A fixed random pose carried rigidly along ``offsets`` (T, 3): features (T - 1, 262)."""
    rng = np.random.default_rng(0)
    pose = rng.normal(0.0, 0.3, (22, 3)) + np.array([0.0, 1.0, 0.0])
    joints = pose[None] + offsets[:, None]
    return joints_to_features(torch.as_tensor(joints, dtype=torch.float32)).numpy()


def test_a_carried_pose_travels_without_moving_its_legs():
    vrd = load_script("vae_root_drift")
    t = np.arange(32) / 30.0  # features drop the last frame: one second at 30 fps
    still = vrd.drift(_person(np.zeros((32, 3))))
    assert np.allclose(still, 0.0, atol=1e-5)
    path, net, ankles = vrd.drift(_person(np.stack([t, 0 * t, 0 * t], axis=1)))  # 1 m/s
    assert abs(path - 1.0) < 1e-3 and abs(net - 1.0) < 1e-3 and ankles < 1e-4


def test_path_counts_wander_that_net_drift_does_not():
    vrd = load_script("vae_root_drift")
    t = np.arange(32) / 30.0
    sway = 0.05 * np.sin(2 * np.pi * 3 * t)  # 5 cm side to side, 3 Hz, back where it began
    path, net, _ = vrd.drift(_person(np.stack([sway, 0 * t, 0 * t], axis=1)))
    assert net < 1e-3 and path > 0.5  # about 4 x 5 cm x 3 per second
