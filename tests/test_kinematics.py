"""One rigid body per person (umf.kinematics): fitting, refinement, foot pins, the floor."""

from __future__ import annotations

from itertools import pairwise

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


# --------------------------------------------------------------------- targets
def test_planted_feet_thresholds_are_strict():
    """Planted: contact label above 0.5 (not at it) and the joint strictly below InterGen's
    contact height (ankle 0.12 m, toe 0.05 m) above the floor (default 0)."""
    joints = np.zeros((4, NUM_JOINTS, 3))
    heights = np.array([0.12, 0.05, 0.12, 0.05])
    joints[0, list(K.FOOT_JOINTS), 1] = heights  # exactly at the contact heights
    joints[1:, list(K.FOOT_JOINTS), 1] = heights - 0.01
    contacts = np.array([[1.0] * 4, [0.5] * 4, [0.6] * 4, [0.6, 0.4, 0.0, 1.0]])
    expected = np.array([[False] * 4, [False] * 4, [True] * 4, [True, False, False, True]])
    np.testing.assert_array_equal(K.planted_feet(joints, contacts), expected)
    np.testing.assert_array_equal(K.planted_feet(joints, contacts, floor=0.0), expected)
    # on a raised floor the same heights above it count
    raised = joints.copy()
    raised[..., 1] += 1.0
    np.testing.assert_array_equal(K.planted_feet(raised, contacts, floor=1.0)[2:], expected[2:])
    assert not K.planted_feet(raised, contacts).any()  # 1 m above the default floor


def test_pin_targets_on_a_hand_made_path():
    """Exact targets and strengths: runs hold their mean, a gap of at most 2 * blend frames
    is interpolated (strength 1), a longer one fades out and in over ``blend`` frames, and
    the clip's ends fade over the frames there are."""
    t = np.arange(40)
    path = np.stack([0.005 * t, np.full(40, 0.01), -0.002 * t], axis=-1)  # slides within reach
    planted = np.zeros(40, dtype=bool)
    planted[2:6] = planted[14:18] = planted[28:38] = True
    assert K.pin_runs(path, planted) == [(2, 6), (14, 18), (28, 38)]
    target, strength = K.pin_targets(path, planted)  # blend 4
    disp = np.zeros((40, 3))
    for a, b in [(2, 6), (14, 18), (28, 38)]:
        disp[a:b] = path[a:b].mean(0) - path[a:b]
    fade = np.array([0.8, 0.6, 0.4, 0.2])
    disp[0:2] = fade[:2][::-1, None] * disp[2]  # the first run fades in from frame 0
    s = np.arange(1, 9)[:, None] / 9  # 8 frames between runs 1 and 2: interpolated
    disp[6:14] = (1 - s) * disp[5] + s * disp[14]
    disp[18:22] = fade[:, None] * disp[17]  # 10 frames between runs 2 and 3: faded
    disp[24:28] = fade[::-1, None] * disp[28]
    disp[38:40] = fade[:2, None] * disp[37]  # the clip ends 2 frames after the last run
    np.testing.assert_allclose(target, path + disp, rtol=0, atol=1e-12)
    expected = np.concatenate([[0.6, 0.8], np.ones(16), fade, [0, 0], fade[::-1],
                               np.ones(10), [0.8, 0.6]])  # fmt: skip
    np.testing.assert_allclose(strength, expected, rtol=0, atol=1e-12)
    assert not np.allclose(disp[5], disp[4])  # the displacement varies within a run
    # a float32 path gets float64 targets
    target32, _ = K.pin_targets(path.astype(np.float32), planted)
    assert target32.dtype == np.float64


def _foot_scene(height: float) -> tuple[np.ndarray, np.ndarray]:
    """20 frames, every joint at the origin but the left ankle (joint 7) at ``height``,
    whose contact label is on in frames 5-14."""
    joints = np.zeros((20, NUM_JOINTS, 3))
    joints[:, K.FOOT_JOINTS[0], 1] = height
    contacts = np.zeros((20, 4))
    contacts[5:15, 0] = 1.0
    return joints, contacts


def test_clean_targets_weights_and_floor():
    """A planted ankle weighs PIN_WEIGHT (1 + 3 x the pin strength while it fades), every
    other joint 1; the contact heights count from ``floor`` (0 without one), and no target
    lies below the floor."""
    strength = np.zeros(20)
    strength[1:5] = [0.2, 0.4, 0.6, 0.8]
    strength[5:15] = 1.0
    strength[15:19] = [0.8, 0.6, 0.4, 0.2]
    pinned = np.ones((20, NUM_JOINTS))
    pinned[:, K.FOOT_JOINTS[0]] = 1.0 + (K.PIN_WEIGHT - 1.0) * strength
    assert (pinned[5:15, 7] == K.PIN_WEIGHT).all()
    joints, contacts = _foot_scene(0.05)  # below the ankle's 0.12 m: planted
    target, weight = K.clean_targets(joints, contacts, None)
    np.testing.assert_allclose(weight, pinned, rtol=0, atol=1e-12)
    np.testing.assert_allclose(target, joints, rtol=0, atol=1e-15)  # the ankle stands still
    assert target.dtype == np.float64
    joints, contacts = _foot_scene(0.5)  # too high above the default floor: free
    target, weight = K.clean_targets(joints, contacts, None)
    np.testing.assert_array_equal(weight, np.ones((20, NUM_JOINTS)))
    joints, contacts = _foot_scene(0.55)  # 5 cm above a floor at 0.5: planted
    target, weight = K.clean_targets(joints, contacts, 0.5)
    np.testing.assert_allclose(weight, pinned, rtol=0, atol=1e-12)
    np.testing.assert_allclose(target[..., 1], np.maximum(joints[..., 1], 0.5), atol=1e-15)
    target, weight = K.clean_targets(joints, None, 0.5)  # the floor alone
    np.testing.assert_array_equal(weight, np.ones((20, NUM_JOINTS)))
    assert target[..., 1].min() == 0.5


# --------------------------------------------------------------------- refinement
def test_cost_is_the_weighted_squared_distance():
    """Per pose: sum over joints of weight x squared distance, for any leading shape."""
    rng = np.random.default_rng(1)
    local = torch.eye(3, dtype=torch.float64).expand(2, 3, NUM_JOINTS, 3, 3)
    root = torch.from_numpy(rng.normal(size=(2, 3, 3)))
    off = default_offsets(torch.float64)
    pos = forward_kinematics(local, root, off)
    delta = torch.from_numpy(rng.normal(0, 0.1, (2, 3, NUM_JOINTS, 3)))
    weight = torch.from_numpy(rng.uniform(0.5, 2.0, (2, 3, NUM_JOINTS)))
    cost = K._cost(local, root, off, pos + delta, weight)
    expected = (weight.numpy() * (delta.numpy() ** 2).sum(-1)).sum(-1)
    assert cost.shape == (2, 3)
    np.testing.assert_allclose(cost.numpy(), expected, rtol=1e-12)


def test_lm_step_pins_the_pelvis_horizontally(monkeypatch):
    """A target that is the pose moved by a shift: the pelvis follows only vertically
    (PINNED_DAMPING on its horizontal shift, on top of the normal equations); without
    that damping the Gauss-Newton step is the shift itself."""
    torch.manual_seed(2)
    local = axis_angle_to_matrix(torch.randn(3, NUM_JOINTS, 3, dtype=torch.float64) * 0.3)
    root = torch.randn(3, 3, dtype=torch.float64)
    off = default_offsets(torch.float64).expand(3, -1, -1)
    target = forward_kinematics(local, root, off) + torch.tensor([0.1, 0.2, -0.3]).double()
    weight = torch.ones(3, NUM_JOINTS, dtype=torch.float64)
    damping = torch.full((3,), 1e-6, dtype=torch.float64)
    _, new_root = K._lm_step(local, root, off, target, weight, damping)
    assert (new_root - root)[:, [0, 2]].abs().max() < 1e-8
    assert ((new_root - root)[:, 1] > 0.1).all()
    monkeypatch.setattr(K, "PINNED_DAMPING", 0.0)
    _, new_root = K._lm_step(local, root, off, target, weight, damping)
    expected = torch.tensor([0.1, 0.2, -0.3], dtype=torch.float64).expand(3, -1)
    assert torch.allclose(new_root - root, expected, atol=1e-4)


def test_refine_keeps_leaf_rotations_and_works_in_float32():
    """Leaves (feet, head, wrists) move nothing: their local rotations come back as they
    were, while the drivers turn. float32 poses stay float32 and get closer."""
    torch.manual_seed(3)
    for dtype in (torch.float64, torch.float32):
        local = axis_angle_to_matrix(torch.randn(4, NUM_JOINTS, 3, dtype=dtype) * 0.4)
        root = torch.zeros(4, 3, dtype=dtype)
        off = default_offsets(dtype)
        pos = forward_kinematics(local, root, off)
        target = pos + 0.03 * torch.randn_like(pos)
        weight = torch.ones(4, NUM_JOINTS, dtype=dtype)
        new_local, new_root = K.refine(local, root, off, target, weight)
        assert new_local.dtype == dtype and new_root.dtype == dtype
        leaves = [j for j in range(NUM_JOINTS) if j not in K.DRIVERS]
        assert leaves == [10, 11, 15, 20, 21]
        tol = 1e-12 if dtype == torch.float64 else 5e-4
        assert (new_local[:, leaves] - local[:, leaves]).abs().max() < tol
        assert (new_local[:, list(K.DRIVERS)] - local[:, list(K.DRIVERS)]).abs().max() > 1e-3
        before = K._cost(local, root, off.expand(4, -1, -1), target, weight)
        after = K._cost(new_local, new_root, off.expand(4, -1, -1), target, weight)
        assert (after < 0.7 * before).all()


def test_refine_rejects_a_step_that_does_not_lower_the_error():
    """float32 poses whose only error is the pelvis 1 m off horizontally (where it is pinned):
    the step's nanometre of pelvis motion does not lower the float32 error, so it is
    rejected every time and the poses come back exactly as they were."""
    torch.manual_seed(4)
    local = axis_angle_to_matrix(torch.randn(2, NUM_JOINTS, 3) * 0.3)
    root = torch.zeros(2, 3)
    off = default_offsets()
    target = forward_kinematics(local, root, off)
    target[:, 0, 0] += 1.0
    weight = torch.zeros(2, NUM_JOINTS)
    weight[:, 0] = 1.0
    new_local, new_root = K.refine(local, root, off, target, weight)
    assert torch.equal(new_root, root) and torch.equal(new_local, local)


def test_refine_damping_schedule(real_joints, monkeypatch):
    """Each pose's damping starts at ``damping``; an accepted step divides it by 3, a
    rejected one multiplies it by 10 (reachable and unreachable targets give both)."""
    raw = torch.from_numpy(real_joints.numpy()[:6])
    bodies = K.fit_bodies(raw.numpy()[None], clean=False, iterations=0)
    local = torch.from_numpy(bodies.rotations[0])
    root = torch.from_numpy(bodies.root[0])
    off = torch.from_numpy(bodies.offsets[0])
    torch.manual_seed(5)
    target = raw + 0.03 * torch.randn_like(raw)
    target[1::2, :, 2] += 2.0  # every other pose 2 m away: unreachable
    weight = torch.ones(6, NUM_JOINTS, dtype=raw.dtype)
    calls = []
    step = K._lm_step

    def recorded(loc, rt, of, tg, wt, lam):
        new = step(loc, rt, of, tg, wt, lam)
        better = K._cost(*new, of, tg, wt) < K._cost(loc, rt, of, tg, wt)
        calls.append((lam.clone(), better))
        return new

    monkeypatch.setattr(K, "_lm_step", recorded)
    K.refine(local, root, off, target, weight, iterations=5, damping=0.01)
    assert len(calls) == 5
    assert torch.allclose(calls[0][0].double(), torch.full((6,), 0.01).double(), rtol=1e-7)
    accepted = torch.stack([b for _, b in calls[:-1]])
    assert accepted.any() and (~accepted).any()
    for (lam, better), (nxt, _) in pairwise(calls):
        assert torch.allclose(nxt, torch.where(better, lam / 3.0, lam * 10.0), rtol=1e-12)


def test_refine_in_blocks_matches_one_block(monkeypatch):
    """Poses are independent: solved in blocks of BLOCK they come back the same."""
    torch.manual_seed(6)
    local = axis_angle_to_matrix(torch.randn(2, 5, NUM_JOINTS, 3, dtype=torch.float64) * 0.3)
    root = torch.randn(2, 5, 3, dtype=torch.float64)
    off = default_offsets(torch.float64)
    pos = forward_kinematics(local, root, off)
    target = pos + 0.03 * torch.randn_like(pos)
    weight = torch.ones(2, 5, NUM_JOINTS, dtype=torch.float64)
    whole = K.refine(local, root, off, target, weight)
    monkeypatch.setattr(K, "BLOCK", 4)
    blocks = K.refine(local, root, off, target, weight)
    assert blocks[0].shape == local.shape and blocks[1].shape == root.shape
    assert torch.allclose(blocks[0], whole[0], atol=1e-6)
    assert torch.allclose(blocks[1], whole[1], atol=1e-6)
    assert not torch.allclose(whole[0], local, atol=1e-3)  # the refinement did something


# --------------------------------------------------------------------- the fit
def test_fit_bodies_validates_its_input(real_joints):
    with pytest.raises(ValueError, match=r"expected joints \(N, T, 22, 3\), got \(1, 5, 21, 3\)"):
        K.fit_bodies(np.zeros((1, 5, 21, 3)))
    with pytest.raises(ValueError, match="expected joints"):
        K.fit_bodies(np.zeros((1, 0, NUM_JOINTS, 3)))
    with pytest.raises(ValueError, match="bones must be 'fit' or 'default', got 'fits'"):
        K.fit_bodies(real_joints.numpy()[None, :3], bones="fits")
    one = K.fit_bodies(real_joints.numpy()[None, :1])  # a single frame is a motion too
    assert one.num_frames == 1
    assert np.abs(one.joints() - real_joints.numpy()[None, :1]).max() < 1e-5


def test_fit_bodies_with_the_default_body(real_joints):
    """bones="default": every person gets the default body's offsets (float64)."""
    joints = np.stack([real_joints.numpy()[:8], real_joints.numpy()[8:16]])
    bodies = K.fit_bodies(joints, bones="default")
    assert bodies.offsets.dtype == np.float64 and bodies.offsets.shape == (2, NUM_JOINTS, 3)
    for offsets in bodies.offsets:
        np.testing.assert_array_equal(offsets, default_offsets(torch.float64).numpy())
    lengths = bone_lengths(torch.from_numpy(bodies.joints()))
    expected = default_offsets(torch.float64).norm(dim=-1)
    assert torch.allclose(lengths, expected.expand_as(lengths), atol=1e-9)


def test_fit_bodies_iterations_are_refinement_steps(real_joints):
    """``iterations`` LM steps from the inverse-kinematics fit, towards the decoded joints."""
    raw = _stretched(real_joints.numpy()[:10])[None]
    ik = K.fit_bodies(raw, clean=False, iterations=0)
    one = K.fit_bodies(raw, clean=False, iterations=1)
    local, root = K.refine(
        torch.from_numpy(ik.rotations[0]), torch.from_numpy(ik.root[0]),
        torch.from_numpy(ik.offsets[0]), torch.from_numpy(raw[0]),
        torch.ones(10, NUM_JOINTS, dtype=torch.float64), iterations=1,
    )  # fmt: skip
    np.testing.assert_allclose(one.rotations[0], local.numpy(), atol=1e-12)
    np.testing.assert_allclose(one.root[0], root.numpy(), atol=1e-12)
    assert np.abs(one.rotations - ik.rotations).max() > 1e-4
    four = K.fit_bodies(raw, clean=False)
    assert np.abs(one.rotations - four.rotations).max() > 1e-4


def test_floor_lifts_each_sunken_frame_by_its_depth(real_joints):
    """Without refinement, the floor lifts each frame whose lowest joint is under it by
    exactly that depth, and leaves the others as they were (clean is the default)."""
    joints = real_joints.numpy()[:20].copy()
    joints[:10, :, 1] -= 0.1  # the first half sinks 6 cm into the floor
    lowest = joints[..., 1].min(-1)
    assert (lowest[:10] < -0.05).all() and (lowest[10:] > 0.04).all()
    out = K.fit_bodies(joints[None], floor=0.0, iterations=0).joints()[0]
    lift = np.maximum(-lowest, 0.0)
    expected = joints.copy()
    expected[..., 1] += lift[:, None]
    assert np.abs(out - expected).max() < 1e-5
    assert np.abs(out[10:] - joints[10:]).max() < 1e-5


def test_floor_is_a_target_so_the_legs_absorb_it(real_joints):
    """Feet sunk 3 cm into the floor: targets are kept on it, so the refinement bends the
    legs, and the final lift (and with it the head) is a fraction of the depth."""
    joints = real_joints.numpy()[:30].copy()
    joints[..., 1] -= joints[..., 1].min() + 0.03
    depth = -joints[..., 1].min(-1)
    out = K.fit_bodies(joints[None], floor=0.0).joints()[0]
    assert out[..., 1].min() >= -1e-9
    head = out[:, 15, 1] - joints[:, 15, 1]
    assert (head < 0.5 * depth).all(), (head, depth)


def test_clean_is_per_person(real_joints):
    """clean=[True, False]: the first person is pinned and kept off the floor, the second
    only fitted (its contacts and the floor ignored), as if fitted alone; contacts are
    optional."""
    walk = real_joints.numpy()[:20].copy()
    walk[..., 1] -= walk[..., 1].min() + 0.02
    joints = np.stack([walk, walk])
    contacts = np.zeros((2, 20, 4))
    contacts[:, 5:15, :2] = 1.0
    bodies = K.fit_bodies(joints, contacts, floor=0.0, clean=[True, False])
    out = bodies.joints()
    assert out[0, ..., 1].min() >= -1e-9
    alone = K.fit_bodies(joints[1:], clean=False)
    np.testing.assert_array_equal(bodies.rotations[1], alone.rotations[0])
    np.testing.assert_array_equal(bodies.root[1], alone.root[0])
    assert out[1, ..., 1].min() < -0.015
    no_contacts = K.fit_bodies(joints, floor=0.0, clean=[True, False]).joints()
    assert no_contacts[0, ..., 1].min() >= -1e-9 and no_contacts[1, ..., 1].min() < -0.015


def test_a_pose_float32_cannot_factor_is_fitted_without_an_error():
    """Every joint on one line, 90 units tall: the normal matrices lose definiteness in
    float32 and the step once raised a LinAlgError out of `umf data show`; now such a row
    is damped again (or takes no step) and the fit ends with finite bodies."""
    line = np.linspace(0, 1.7, NUM_JOINTS)[:, None].repeat(3, axis=1) * 30
    joints = np.repeat(line[None, None], 8, axis=1).astype(np.float32)
    normal = torch.zeros(2, 4, 4)
    normal[0] = torch.eye(4)
    normal[1, 0, 0] = -1.0  # cannot factor, even damped again: no step
    grad = torch.ones(2, 4)
    chol, info = torch.linalg.cholesky_ex(normal)
    chol, grad = K._steady(normal, grad, info != 0, chol)
    assert torch.equal(chol[0], torch.eye(4)) and torch.equal(grad[0], torch.ones(4))
    assert torch.equal(grad[1], torch.zeros(4))  # a row that still does not factor stays
    bodies = K.fit_bodies(joints, clean=False)
    assert np.isfinite(bodies.joints()).all()
