"""One rigid body per person (umf.kinematics): fitting, refinement, foot pins, the floor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from umf import kinematics as K
from umf.rotations import axis_angle_to_matrix
from umf.skeleton import (
    NUM_JOINTS,
    PARENTS,
    bone_lengths,
    default_offsets,
    forward_kinematics,
    global_rotations,
)


def _stretched(joints: np.ndarray, amount: float = 0.08, seed: int = 0) -> np.ndarray:
    """Joints (T, 22, 3) whose bones stretch and shrink over time (by up to ``amount``
    relative), like a decoder's: each bone vector is scaled, children follow."""
    rng = np.random.default_rng(seed)
    t = len(joints)
    phase = rng.uniform(0, 2 * np.pi, NUM_JOINTS)
    scale = 1 + amount * np.sin(np.linspace(0, 4 * np.pi, t)[:, None] + phase)
    out = joints.copy()
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        out[:, j] = out[:, p] + (joints[:, j] - joints[:, p]) * scale[:, j, None]
    return out


def test_normal_equations_match_autograd():
    """The analytic J^T W J and J^T W r equal those of autograd's Jacobian of the very
    update _lm_step applies (root shift + per-driver world rotations)."""
    torch.manual_seed(0)
    local = axis_angle_to_matrix(torch.randn(1, NUM_JOINTS, 3, dtype=torch.float64) * 0.5)
    root = torch.randn(1, 3, dtype=torch.float64)
    off = default_offsets(torch.float64)[None]
    pos = forward_kinematics(local, root, off)
    target = pos + 0.05 * torch.randn_like(pos)
    weight = torch.rand(1, NUM_JOINTS, dtype=torch.float64) + 0.5
    upto = torch.from_numpy(K._UPTO)

    def moved(params):
        omega = params[3:].reshape(len(K.DRIVERS), 3)
        glob = global_rotations(local)[0].clone()
        total = torch.einsum("ad,ac->dc", upto, omega)
        glob[list(K.DRIVERS)] = axis_angle_to_matrix(total) @ glob[list(K.DRIVERS)]
        for j in range(1, NUM_JOINTS):
            if j not in K.DRIVERS:
                glob[j] = glob[PARENTS[j]] @ local[0, j]
        new = glob[[max(p, 0) for p in PARENTS]].transpose(-1, -2) @ glob
        new[0] = glob[0]
        return forward_kinematics(new[None], root + params[:3], off)[0].reshape(-1)

    n = 3 + 3 * len(K.DRIVERS)
    jac = torch.autograd.functional.jacobian(moved, torch.zeros(n, dtype=torch.float64))
    w = weight[0].repeat_interleave(3)
    normal, grad = K.normal_equations(pos, target - pos, weight)
    ref_n = jac.T @ (w[:, None] * jac)
    ref_g = jac.T @ (w * (target - pos)[0].reshape(-1))
    assert torch.allclose(normal[0].double(), ref_n, atol=1e-5 * ref_n.abs().max())
    assert torch.allclose(grad[0].double(), ref_g, atol=1e-5 * ref_g.abs().max())


def test_rigid_motion_is_reproduced(real_joints):
    """A real (rigid) clip comes back unchanged: FK of the fitted rotations is the input."""
    joints = real_joints.numpy()[None]
    bodies = K.fit_bodies(joints, clean=False)
    assert np.abs(bodies.joints() - joints).max() < 1e-6
    assert bodies.rotations.shape == (1, joints.shape[1], NUM_JOINTS, 3, 3)


def test_stretching_bones_become_one_body(real_joints):
    """Stretched bones: one length per bone, and the refinement brings the joints closer to
    the stretched input than inverse kinematics alone (whose errors add up along chains)."""
    raw = _stretched(real_joints.numpy())[None]
    ik = K.fit_bodies(raw, clean=False, iterations=0).joints()
    fit = K.fit_bodies(raw, clean=False).joints()
    lengths = bone_lengths(torch.from_numpy(fit))
    assert (lengths.max(1).values - lengths.min(1).values).max() < 1e-9
    err_ik = np.linalg.norm(ik - raw, axis=-1)
    err_fit = np.linalg.norm(fit - raw, axis=-1)
    assert err_fit.mean() < 0.8 * err_ik.mean() and err_fit.max() < err_ik.max()


def test_refinement_never_raises_the_error(real_joints):
    """Levenberg-Marquardt with rejected steps: unreachable targets cannot make it worse."""
    raw = torch.from_numpy(_stretched(real_joints.numpy()[:30], 0.3))
    bodies = K.fit_bodies(raw.numpy()[None], clean=False, iterations=0)
    local = torch.from_numpy(bodies.rotations[0])
    root = torch.from_numpy(bodies.root[0])
    off = torch.from_numpy(bodies.offsets[0])
    target = (
        raw + torch.tensor([0.0, 0.0, 2.0], dtype=raw.dtype) * (torch.arange(30) % 2)[:, None, None]
    )  # every other frame 2 m away: far beyond any limb
    weight = torch.ones(30, NUM_JOINTS, dtype=raw.dtype)
    before = K._cost(local, root, off.expand(30, -1, -1), target, weight)
    new_local, new_root = K.refine(local, root, off, target, weight)
    after = K._cost(new_local, new_root, off.expand(30, -1, -1), target, weight)
    assert (after <= before + 1e-9).all()


def test_pins_hold_planted_feet_and_the_floor(bandai_clips):
    """A standing person whose planted foot slides a few centimetres and sinks into the
    floor: the fit holds the foot still and nobody goes below the floor."""
    bow = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001")
    joints = bow.joints[0][:60].astype(np.float64)
    joints[..., 1] -= joints[..., 1].min() + 0.02  # 2 cm into the floor
    drift = np.linspace(0, 0.05, 60)[:, None]  # the whole body slides 5 cm along X
    joints[..., 0] += drift
    contacts = np.zeros((60, 4))
    contacts[10:50, 0:2] = 1.0  # left ankle and toes planted for 40 frames
    low = joints[10:50, [7, 10], 1].max(0)
    assert (low < np.array([0.12, 0.05])).all()  # low enough to be planted
    bodies = K.fit_bodies(joints[None], contacts[None], floor=0.0, clean=True)
    out = bodies.joints()[0]
    assert out[..., 1].min() >= -1e-9
    before = np.linalg.norm(np.diff(joints[10:50, [7, 10]][..., [0, 2]], axis=0), axis=-1)
    after = np.linalg.norm(np.diff(out[10:50, [7, 10]][..., [0, 2]], axis=0), axis=-1)
    assert after.mean() < 0.3 * before.mean(), (after.mean(), before.mean())
    # the legs hold the foot; the pelvis keeps the decoded horizontal path (where people
    # stand is the model's and the separation's): undamped, the pin pulls it 0.5 mm here
    pelvis = np.abs(out[:, 0, [0, 2]] - joints[:, 0, [0, 2]]).max()
    assert pelvis < 1e-4, pelvis
    # no clean-up for a person who is only fitted (a user's actor)
    plain = K.fit_bodies(joints[None], contacts[None], floor=0.0, clean=False).joints()[0]
    assert plain[..., 1].min() < -0.01


def test_pin_targets_are_continuous():
    """Pins fade in and out: a foot target never jumps, and inside a run it stands still."""
    t = np.arange(80)
    path = np.stack([0.02 * t, np.full(80, 0.05), np.zeros(80)], axis=-1)  # slides 0.6 m/s
    planted = (t >= 20) & (t < 60)
    target, strength = K.pin_targets(path, planted)
    runs = K.pin_runs(path, planted)
    assert runs and all(b - a >= 2 for a, b in runs)
    for a, b in runs:
        assert np.ptp(target[a:b], axis=0).max() < 1e-12 and (strength[a:b] == 1).all()
    step = np.linalg.norm(np.diff(target, axis=0), axis=-1)
    assert step.max() < 0.05  # the decoded path moves 2 cm a frame; catching up stays smooth
    assert np.allclose(target[:10], path[:10]) and np.allclose(target[-10:], path[-10:])


def test_bodies_shapes_and_frames():
    b = K.fit_bodies(np.random.default_rng(0).normal(size=(2, 20, 22, 3)), clean=False)
    assert b.num_people == 2 and b.num_frames == 20
    part = b.frames(10, 2)
    assert part.num_frames == 8
    assert np.allclose(part.joints(), b.joints()[:, 2:10])
    with pytest.raises(ValueError):
        K.Bodies(b.offsets, b.rotations[:, :5], b.root)
    with pytest.raises(ValueError):
        K.fit_bodies(np.zeros((5, 22, 3)))


def test_ancestry_masks_follow_the_smpl_tree():
    """Written out from SMPL-22's tree: which joints a driver's rotation moves (the
    Jacobian's mask) and which drivers a driver's world rotation composes."""
    below, upto = K._ancestry()
    drivers = list(K.DRIVERS)
    assert drivers == [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 13, 14, 16, 17, 18, 19]  # not leaves
    moved = {0: set(range(1, 22)), 9: {12, 13, 14, 15, 16, 17, 18, 19, 20, 21},
             1: {4, 7, 10}, 4: {7, 10}, 7: {10}, 16: {18, 20}, 18: {20}, 12: {15}}  # fmt: skip
    for j, joints in moved.items():
        assert set(np.flatnonzero(below[:, drivers.index(j)])) == joints, j
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    depth = [0] * 22
    for k in range(1, 22):
        depth[k] = depth[parents[k]] + 1
    assert below.sum() == sum(depth)  # each joint is below each of its ancestors, once
    assert upto.sum() == sum(depth[j] + 1 for j in drivers)
    chains = {0: {0}, 9: {0, 3, 6, 9}, 19: {0, 3, 6, 9, 14, 17, 19}, 7: {0, 1, 4, 7}}
    for j, above in chains.items():
        assert {drivers[a] for a in np.flatnonzero(upto[:, drivers.index(j)])} == above, j
    np.testing.assert_array_equal(K._BELOW, below)
    np.testing.assert_array_equal(K._UPTO, upto)


def test_bodies_frames_and_person_are_copied_slices():
    rng = np.random.default_rng(0)
    rot = np.tile(np.eye(3), (2, 10, 22, 1, 1)) + rng.normal(0, 1e-3, (2, 10, 22, 3, 3))
    bodies = K.Bodies(rng.normal(size=(2, 22, 3)), rot, rng.normal(size=(2, 10, 3)))
    part = bodies.frames(7, 2)
    np.testing.assert_array_equal(part.rotations, bodies.rotations[:, 2:7])
    np.testing.assert_array_equal(part.root, bodies.root[:, 2:7])
    np.testing.assert_array_equal(part.offsets, bodies.offsets)
    part.offsets[:] = 0.0
    part.root[:] = 0.0
    part.rotations[:] = 0.0
    assert bodies.offsets.any() and bodies.root[:, 2:7].any() and bodies.rotations.any()
    head = bodies.frames(4)
    assert head.num_frames == 4 and head.num_people == 2
    np.testing.assert_array_equal(head.root, bodies.root[:, :4])
    one = bodies.person(1)
    assert one.num_people == 1
    np.testing.assert_array_equal(one.root, bodies.root[1:2])
    np.testing.assert_array_equal(one.offsets, bodies.offsets[1:2])
    np.testing.assert_array_equal(one.rotations, bodies.rotations[1:2])
    with pytest.raises(ValueError, match="inconsistent bodies"):
        K.Bodies(bodies.offsets, bodies.rotations[:, :9], bodies.root)
    with pytest.raises(ValueError, match="inconsistent bodies"):
        K.Bodies(bodies.offsets[:1], bodies.rotations, bodies.root)


def test_pin_runs_on_a_hand_made_contact_sequence():
    """Runs start at planted frames (frame 0 too), end where contact ends or the decoded
    foot slides past ``reach`` (inclusive), and a let-go pin waits ``gap`` frames."""
    planted = np.array([1, 1, 0, 1, 1, 1, 1, 1, 1, 0, 1], dtype=bool)
    x = np.array([0, 0, 0, 0, 0.05, 0.1, 0.2, 0.21, 0.22, 0, 0], dtype=float)
    path = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)
    # 0-1 planted; 3-5 within 0.1 of frame 3 (0.1 exactly counts), 6 slides past: let go
    # for 2 frames (6, 7), pinned again at 8 until contact ends at 9; 10 planted to the end
    assert K.pin_runs(path, planted, reach=0.1, gap=2) == [(0, 2), (3, 6), (8, 9), (10, 11)]
    assert K.pin_runs(path, planted, reach=0.1, gap=1) == [(0, 2), (3, 6), (7, 9), (10, 11)]
    assert K.pin_runs(path, np.zeros(11, dtype=bool)) == []
    assert K.pin_runs(path, np.ones(11, dtype=bool), reach=1.0) == [(0, 11)]
