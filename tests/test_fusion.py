"""Decoded positions made consistent with decoded velocities (representation.fuse_positions)."""

from __future__ import annotations

import torch

from umf.representation import POS, VEL, fuse_positions, joints_to_features


def test_consistent_features_are_a_fixed_point(real_joints):
    f = joints_to_features(real_joints[:61])
    fused = fuse_positions(f, 0.1)
    assert torch.allclose(fused, f, atol=1e-9)


def test_frame_noise_is_removed_and_the_path_kept(real_joints):
    """Frame-to-frame noise of 3 cm on the positions, truthful velocities: the fused
    positions are close to the truth (much closer than the noisy ones) and smooth."""
    f = joints_to_features(real_joints[:91])
    gen = torch.Generator().manual_seed(0)
    noisy = f.clone()
    noisy[:, POS] += 0.03 * torch.randn(noisy[:, POS].shape, generator=gen, dtype=f.dtype)
    fused = fuse_positions(noisy, 0.1)
    err_noisy = (noisy[:, POS] - f[:, POS]).abs().mean()
    err_fused = (fused[:, POS] - f[:, POS]).abs().mean()
    assert err_fused < 0.3 * err_noisy
    # velocity slots are the differences of the fused positions
    assert torch.allclose(fused[1:, POS] - fused[:-1, POS], fused[:-1, VEL], atol=1e-9)
    # zero weight: untouched; batched input gives the same as one at a time
    assert torch.equal(fuse_positions(noisy, 0.0), noisy)
    both = fuse_positions(torch.stack([noisy, f]), 0.1)
    assert torch.allclose(both[0], fused, atol=1e-9) and torch.allclose(both[1], f, atol=1e-9)


def test_drift_in_velocities_is_anchored_by_positions(real_joints):
    """Velocities biased by 1 cm/frame would drift 0.9 m over 90 frames when integrated;
    the positions keep the fused path within centimetres of the truth on average."""
    f = joints_to_features(real_joints[:91])
    biased = f.clone()
    biased[:, VEL] += 0.01
    err = (fuse_positions(biased, 0.1)[:, POS] - f[:, POS]).abs().mean()
    assert err < 0.1


def test_root_weight_smooths_the_path_only(real_joints):
    """A pelvis path with frame noise: a small root weight removes it, the pose relative to
    the pelvis is fused with its own weight and stays the same."""
    f = joints_to_features(real_joints[:91])
    noisy = f.clone()
    gen = torch.Generator().manual_seed(1)
    shake = 0.05 * torch.randn(91 - 1, 1, 3, generator=gen, dtype=f.dtype)
    noisy[:, POS] = (noisy[:, POS].reshape(-1, 22, 3) + shake).reshape(-1, 66)  # whole body
    loose, tight = fuse_positions(noisy, 0.1, 0.005), fuse_positions(noisy, 0.1)
    root = slice(0, 3)
    err = [(x[:, root] - f[:, root]).abs().mean() for x in (loose, tight)]
    assert err[0] < err[1]
    rel = [
        (x[:, POS].reshape(-1, 22, 3) - x[:, POS].reshape(-1, 22, 3)[:, :1]) for x in (loose, tight)
    ]
    assert torch.allclose(rel[0], rel[1], atol=1e-9)


def test_height_weight_fuses_the_pelvis_height_on_its_own(real_joints):
    """height_weight: the pelvis's height is fused with its own weight, the floor path and
    the pose keep theirs. Velocities biased upward would lift a pelvis fused at a small
    weight off its decoded height; weight 1 keeps it there."""
    f = joints_to_features(real_joints[:91])
    biased = f.clone()
    up = torch.tensor([0.0, 0.005, 0.0], dtype=f.dtype)  # 5 mm per frame upward
    biased[:, VEL] = (biased[:, VEL].reshape(-1, 22, 3) + up).reshape(-1, 66)
    loose = fuse_positions(biased, 1.0, 0.0002)
    split = fuse_positions(biased, 1.0, 0.0002, 1.0)
    height = fuse_positions(biased, 1.0, 1.0)
    y, xz = 1, [0, 2]
    assert torch.allclose(split[:, xz], loose[:, xz], atol=1e-9)  # pelvis floor path
    assert torch.allclose(split[:, y], height[:, y], atol=1e-9)  # pelvis height
    rel = [
        x[:, POS].reshape(-1, 22, 3) - x[:, POS].reshape(-1, 22, 3)[:, :1] for x in (split, loose)
    ]
    assert torch.allclose(rel[0], rel[1], atol=1e-9)  # the pose relative to the pelvis
    err = [(x[:, y] - f[:, y]).abs().max() for x in (loose, split)]
    assert err[1] < 0.02 < err[0]
    assert torch.equal(
        fuse_positions(biased, 1.0, 0.005, 0.005), fuse_positions(biased, 1.0, 0.005)
    )
    batch = torch.stack([torch.stack([biased, f]), torch.stack([f, biased])])  # (2, 2, T, 262)
    fused = fuse_positions(batch, 1.0, 0.0002, 1.0)
    assert torch.allclose(fused[0, 0], split, atol=1e-9)
    assert torch.allclose(fused[1, 0], fuse_positions(f, 1.0, 0.0002, 1.0), atol=1e-9)
    assert fuse_positions(batch[:, :0], 1.0, 0.0002, 1.0).shape == (2, 0, *f.shape)  # no one
