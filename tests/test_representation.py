import math

import pytest
import torch

from umf import representation as rep
from umf.rotations import yaw_matrix
from umf.skeleton import fit_offsets, forward_kinematics, inverse_kinematics


def test_feature_layout_round_trip(real_joints):
    f = rep.joints_to_features(real_joints)
    t = real_joints.shape[0]
    assert f.shape == (t - 1, rep.FEATURE_DIM)
    # positions come back exactly, velocities are forward differences
    assert torch.equal(rep.features_to_joints(f), real_joints[:-1])
    assert torch.allclose(rep.features_to_joints_integrated(f), real_joints, atol=1e-12)
    vel = f[:, rep.VEL].reshape(t - 1, 22, 3)
    assert torch.allclose(vel[5, 7], real_joints[6, 7] - real_joints[5, 7])
    # rotations in the feature reproduce the joints through FK
    local = rep.features_to_local_rotations(f)
    root = inverse_kinematics(real_joints[:-1])[:, :1]
    offsets = fit_offsets(real_joints)
    back = forward_kinematics(torch.cat([root, local], dim=1), real_joints[:-1, 0], offsets)
    assert (back - real_joints[:-1]).norm(dim=-1).max() < 1e-4


def test_rejects_bad_shapes():
    with pytest.raises(ValueError):
        rep.joints_to_features(torch.zeros(10, 21, 3))
    with pytest.raises(ValueError):
        rep.joints_to_features(torch.zeros(1, 22, 3))


def test_foot_contacts_rule():
    j = torch.zeros(4, 22, 3, dtype=torch.float64)
    j[:, :, 1] = 1.0  # everyone high up
    j[:, 7, 1] = 0.10  # left ankle low and still -> contact
    j[:, 10, 1] = 0.10  # left toe low but above toe threshold 0.05 -> no contact
    j[:, 8, 1] = 0.01  # right ankle low ...
    j[:, 8, 0] = torch.arange(4) * 0.05  # ... but sliding 5 cm/frame: 0.0025 > 0.001
    j[:, 11, 1] = 0.01
    c = rep.foot_contacts(j)
    assert c.shape == (3, 4)
    assert c[:, 0].tolist() == [1, 1, 1]  # l_ankle
    assert c[:, 1].tolist() == [0, 0, 0]  # l_foot
    assert c[:, 2].tolist() == [0, 0, 0]  # r_ankle slides
    assert c[:, 3].tolist() == [1, 1, 1]  # r_foot


def test_real_walk_has_alternating_contacts(real_joints):
    c = rep.foot_contacts(real_joints)
    left, right = c[:, :2].amax(1), c[:, 2:].amax(1)
    assert 0.2 < left.mean() < 0.9 and 0.2 < right.mean() < 0.9
    assert (left + right >= 1).float().mean() > 0.8  # nearly always a foot down


def test_canonical_frame(real_joints):
    turned = real_joints @ yaw_matrix(torch.tensor(1.0, dtype=torch.float64)).T
    turned = turned + torch.tensor([3.0, 0.2, -1.0], dtype=torch.float64)
    canon, tf = rep.canonicalize_scene(turned[None])
    canon = canon[0]
    assert abs(float(canon[0, 0, 0])) < 1e-9 and abs(float(canon[0, 0, 2])) < 1e-9
    assert abs(float(canon[..., 1].min())) < 1e-9
    assert abs(float(rep.heading_angle(canon[0]))) < 1e-6
    # the walk goes forward (+Z) in the canonical frame
    assert canon[-1, 0, 2] > 5.0
    assert torch.allclose(tf.invert(canon), turned, atol=1e-9)


def test_leader_frame_is_the_training_crops_frame(real_joints):
    """A person moved by leader_frame lands where canonicalize_features puts person 1 of a
    training crop (pelvis over the origin, facing +Z, heights kept), and back again."""
    turned = real_joints @ yaw_matrix(torch.tensor(2.0, dtype=torch.float64)).T
    f = rep.joints_to_features(turned + torch.tensor([3.0, 0.1, -1.0], dtype=torch.float64))
    tf = rep.leader_frame(f)
    placed = rep.transform_features(f, tf)
    assert torch.allclose(placed, rep.canonicalize_features(f), atol=1e-9)
    j0 = rep.features_to_joints(placed[0])
    assert abs(float(j0[0, 0])) < 1e-9 and abs(float(j0[0, 2])) < 1e-9
    assert abs(float(rep.heading_angle(j0))) < 1e-9
    assert torch.allclose(rep.features_to_joints(placed)[..., 1], rep.features_to_joints(f)[..., 1])
    assert torch.allclose(rep.transform_features(placed, tf, inverse=True), f, atol=1e-9)


def test_scene_keeps_relative_placement(real_joints):
    other = real_joints + torch.tensor([1.5, 0.0, 0.0], dtype=torch.float64)
    scene = torch.stack([real_joints, other])
    canon, _ = rep.canonicalize_scene(scene)
    d0 = (scene[1, :, 0] - scene[0, :, 0]).norm(dim=-1)
    d1 = (canon[1, :, 0] - canon[0, :, 0]).norm(dim=-1)
    assert torch.allclose(d0, d1)


def test_heading_convention():
    # a person turned by +90 degrees about +Y faces +X
    from umf.skeleton import default_offsets

    rot = torch.eye(3).repeat(22, 1, 1)
    rot[0] = yaw_matrix(torch.tensor(math.pi / 2))
    j = forward_kinematics(rot, torch.zeros(3), default_offsets())
    assert torch.allclose(rep.facing_direction(j), torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)
    assert abs(float(rep.heading_angle(j)) - math.pi / 2) < 1e-5


def test_mirror(real_joints):
    m = rep.mirror_joints(real_joints)
    # left and right swap, X flips
    assert torch.allclose(m[:, 1, 0], -real_joints[:, 2, 0])
    assert torch.equal(rep.mirror_joints(m), real_joints)
    f = rep.joints_to_features(real_joints)
    fm = rep.mirror_features(f)
    # mirroring features equals featurising the mirrored joints (positions, velocities,
    # contacts exactly; rotations up to the IK of the mirrored skeleton)
    ref = rep.joints_to_features(m)
    assert torch.allclose(fm[:, :132], ref[:, :132], atol=1e-12)
    assert torch.equal(fm[:, rep.CONTACT], ref[:, rep.CONTACT])
    rot_m = rep.features_to_local_rotations(fm)
    rot_ref = rep.features_to_local_rotations(ref)
    assert (rot_m - rot_ref).abs().max() < 1e-3
    assert torch.allclose(rep.mirror_features(fm), f, atol=1e-9)


def test_normalizer_round_trip(tmp_path, real_joints):
    f = rep.joints_to_features(real_joints).float()
    norm = rep.Normalizer.fit(f)
    z = norm.normalize(f)
    moving = norm.std[: rep.CONTACT.start] > 0.011
    assert torch.allclose(
        z[:, : rep.CONTACT.start].mean(0)[moving], torch.zeros(int(moving.sum())), atol=1e-3
    )
    assert torch.allclose(norm.denormalize(z), f, atol=1e-5)
    assert torch.equal(z[:, rep.CONTACT], f[:, rep.CONTACT])  # labels stay 0/1
    norm.save(tmp_path / "n.safetensors")
    back = rep.Normalizer.load(tmp_path / "n.safetensors")
    assert torch.equal(back.mean, norm.mean) and torch.equal(back.std, norm.std)


def test_transform_features_moves_positions_and_turns_velocities_both_ways(real_joints):
    """Features moved into a frame are the features of the moved joints, velocities
    included, and ``inverse`` moves them back out: a velocity turned the wrong way (the
    react path moves people 2..N out of the model's frame this way) is 2 sin(yaw/2) of the
    speed off."""
    tf = rep.RigidTransform(yaw=1.1, origin=(0.7, 0.0, -1.3))  # on the floor: same contacts
    f = rep.joints_to_features(real_joints)
    moved = rep.transform_features(f, tf)
    want = rep.joints_to_features(tf.apply(real_joints))
    torch.testing.assert_close(moved[..., rep.VEL], want[..., rep.VEL], atol=1e-12, rtol=0)
    torch.testing.assert_close(moved, want, atol=1e-12, rtol=0)
    out = rep.transform_features(want, tf, inverse=True)
    torch.testing.assert_close(out, f, atol=1e-12, rtol=0)
    back = rep.joints_to_features(tf.invert(real_joints))
    torch.testing.assert_close(rep.transform_features(f, tf, inverse=True), back,
                               atol=1e-12, rtol=0)  # fmt: skip


def test_check_joints_messages_and_two_frames_suffice():
    with pytest.raises(ValueError, match=r"^expected joints \(T, 22, 3\), got \(10, 21, 3\)$"):
        rep.joints_to_rot6d(torch.zeros(10, 21, 3))
    with pytest.raises(ValueError, match=r"^need at least 2 frames to compute velocities$"):
        rep.assemble_features(torch.zeros(1, 22, 3), torch.zeros(1, 21, 6))
    # two frames are enough: one feature frame, its velocity the one difference
    j = torch.zeros(2, 22, 3, dtype=torch.float64)
    j[1, :, 2] = 0.25
    f = rep.assemble_features(j, torch.zeros(2, 21, 6, dtype=torch.float64))
    assert f.shape == (1, rep.FEATURE_DIM)
    assert torch.equal(f[0, rep.VEL].reshape(22, 3)[:, 2], torch.full((22,), 0.25).double())


def test_assemble_features_takes_the_joints_dtype(real_joints):
    """Rotations of another precision are cast to the joints' dtype, not the other way."""
    rot6d = rep.joints_to_rot6d(real_joints[:5])
    f32 = rep.assemble_features(real_joints[:5].float(), rot6d)  # float64 rotations
    assert f32.dtype == torch.float32
    assert torch.equal(f32[:, rep.ROT], rot6d[:-1].reshape(4, 126).float())
    f64 = rep.assemble_features(real_joints[:5], rot6d.float())
    assert f64.dtype == torch.float64
    assert torch.equal(f64[:, rep.ROT], rot6d[:-1].reshape(4, 126).float().double())


def test_foot_contacts_thresholds_are_strict():
    """A foot exactly at a height threshold, or moving exactly at the speed threshold, is
    not in contact (``<``, compared in the joints' own precision); just below it is."""
    j = torch.ones(3, 22, 3, dtype=torch.float64)
    j[:, 7, 1] = 0.12  # l_ankle exactly at the ankle threshold
    j[:, 10, 1] = 0.05  # l_foot exactly at the toe threshold
    j[:, 8, 1] = 0.12 - 1e-9  # r_ankle just below
    j[:, 11] = 0.0  # r_foot on the floor at the origin ...
    j[1:, 11, 0] = 0.01  # ... moving (0.01, 0, 0.03) in frame 0: exactly the threshold
    j[1:, 11, 2] = 0.03
    disp2 = ((j[1:, 11] - j[:-1, 11]) ** 2).sum(-1)
    assert disp2.tolist() == [rep.CONTACT_VELOCITY_THRESHOLD, 0.0]
    c = rep.foot_contacts(j)
    assert c.dtype == torch.float64
    assert c.tolist() == [[0, 0, 1, 0], [0, 0, 1, 1]]


def _stacked(walk):
    return torch.stack([walk, rep.place_features(walk, 2.0, 3.0, -1.0)])


@pytest.mark.parametrize(
    "fn",
    [
        rep.features_to_joints_integrated,
        rep.features_to_local_rotations,
        rep.mirror_features,
        lambda f: rep.place_features(f, 0.8, -0.5, 1.5),
        lambda f: rep.transform_features(f, rep.RigidTransform(1.1, (0.7, 0.0, -1.3))),
    ],
    ids=["integrated", "local_rotations", "mirror", "place", "transform"],
)
def test_feature_functions_work_on_batches(real_joints, fn):
    """(P, T, 262) gives what each (T, 262) gives on its own."""
    walk = rep.joints_to_features(real_joints[:20])
    scene = _stacked(walk)
    out = fn(scene)
    want = torch.stack([fn(scene[0]), fn(scene[1])])
    assert out.shape == want.shape
    assert torch.allclose(out, want, atol=1e-12)


def test_foot_contacts_on_a_batch(real_joints):
    j = real_joints[:20]
    both = torch.stack([j, j.flip(-1)])  # the second person on a wall: no contacts
    c = rep.foot_contacts(both)
    assert c.shape == (2, 19, 4)
    assert torch.equal(c[0], rep.foot_contacts(j))
    assert torch.equal(c[1], rep.foot_contacts(j.flip(-1)))


def test_facing_direction_per_pose_in_a_batch():
    """Three poses (a batch of 3: a size the cross product must not take as the vector
    axis) turned by three yaws face (sin, 0, cos) each, every one of unit length."""
    from umf.skeleton import default_offsets

    yaws = [0.3, 2.0, -1.2]
    poses = []
    for k, yaw in enumerate(yaws):
        rot = torch.eye(3).repeat(22, 1, 1)
        rot[0] = yaw_matrix(torch.tensor(yaw))
        poses.append(forward_kinematics(rot, torch.tensor([k, 0.9, -k]), default_offsets()))
    j = torch.stack(poses)  # (3, 22, 3)
    fwd = rep.facing_direction(j)
    want = torch.tensor([[math.sin(y), 0.0, math.cos(y)] for y in yaws])
    assert fwd.shape == (3, 3)
    assert torch.allclose(fwd, want, atol=1e-5)
    assert torch.allclose(fwd.norm(dim=-1), torch.ones(3))


def test_canonicalize_features_uses_person_one(real_joints):
    """A scene (P, T, 262) moves with person 1's first frame, whatever person 2 does."""
    walk = rep.joints_to_features(real_joints[:20])
    one = rep.place_features(walk, 2.0, 3.0, -1.0)
    two = rep.place_features(walk, -0.7, -2.0, 0.5)
    canon = rep.canonicalize_features(torch.stack([one, two]))
    assert canon.shape == (2, 19, rep.FEATURE_DIM)
    assert torch.allclose(canon[0], rep.canonicalize_features(one), atol=1e-9)
    tf = rep.leader_frame(one)
    assert torch.allclose(canon[1], rep.transform_features(two, tf), atol=1e-9)
    j0 = rep.features_to_joints(canon[0, 0])
    assert abs(float(j0[0, 0])) < 1e-9 and abs(float(j0[0, 2])) < 1e-9


# ------------------------------------------------------------------ fuse_positions
def _least_squares(p, v, w):
    """argmin_P w sum_t |P_t - p_t|^2 + sum_t<T-1 |P_{t+1} - P_t - v_t|^2, columnwise,
    by a stacked least-squares problem (rows written out one by one)."""
    t = p.shape[0]
    rows, rhs = [], []
    for i in range(t):
        row = torch.zeros(t, dtype=torch.float64)
        row[i] = math.sqrt(w)
        rows.append(row)
        rhs.append(math.sqrt(w) * p[i])
    for i in range(t - 1):
        row = torch.zeros(t, dtype=torch.float64)
        row[i + 1], row[i] = 1.0, -1.0
        rows.append(row)
        rhs.append(v[i])
    return torch.linalg.lstsq(torch.stack(rows), torch.stack(rhs), driver="gelsd").solution


def _reference_fuse(f, w, root_w=None, height_w=None):
    """The documented split: the pose relative to the pelvis at ``w``, the pelvis's floor
    path (x, z) at ``root_w`` (default ``w``), its height at ``height_w`` (default
    ``root_w``); velocity slots the fused differences, the last one kept."""
    root_w = w if root_w is None else root_w
    height_w = root_w if height_w is None else height_w
    t = f.shape[0]
    pos, vel = f[:, rep.POS].reshape(t, 22, 3), f[:, rep.VEL].reshape(t, 22, 3)
    root, root_vel = pos[:, :1], vel[:, :1]
    rel = _least_squares((pos - root).reshape(t, 66), (vel - root_vel).reshape(t, 66), w)
    path = torch.stack(
        [_least_squares(root[:, 0, c], root_vel[:, 0, c], height_w if c == 1 else root_w)
         for c in range(3)], dim=-1)  # fmt: skip
    fused = (rel.reshape(t, 22, 3) + path[:, None]).reshape(t, 66)
    out = f.clone()
    out[:, rep.POS] = fused
    out[:-1, rep.VEL] = fused[1:] - fused[:-1]
    return out


def _noisy_features(t, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(t, rep.FEATURE_DIM, generator=gen, dtype=torch.float64)


@pytest.mark.parametrize(
    "weights",
    [(0.1,), (1.5,), (0.1, 2.5), (0.1, 2.5, 0.3), (0.7, None, 0.05)],
    ids=["w", "w>1", "root", "root+height", "height"],
)
def test_fuse_positions_minimises_the_documented_objective(weights):
    f = _noisy_features(7)
    out = rep.fuse_positions(f, *weights)
    want = _reference_fuse(f, *weights)
    torch.testing.assert_close(out, want, atol=1e-12, rtol=0)
    assert torch.equal(out[:, rep.ROT.start :], f[:, rep.ROT.start :])  # rotations, contacts
    assert torch.equal(out[-1, rep.VEL], f[-1, rep.VEL])  # the last velocity is kept
    assert not torch.allclose(out[:, rep.POS], f[:, rep.POS], atol=1e-3)


def test_fuse_positions_two_frames_and_no_op_cases():
    f = _noisy_features(2, seed=1)
    torch.testing.assert_close(rep.fuse_positions(f, 0.4), _reference_fuse(f, 0.4),
                               atol=1e-12, rtol=0)  # fmt: skip
    # zero weight or one frame: nothing to fuse, the input comes back as it is
    assert rep.fuse_positions(f, 0.0) is f
    one = _noisy_features(1)
    assert rep.fuse_positions(one, 0.4) is one


def test_fuse_positions_batched_and_empty():
    a, b = _noisy_features(6, seed=2), _noisy_features(6, seed=3)
    both = rep.fuse_positions(torch.stack([a, b]), 0.2, 0.05, 1.0)
    want = torch.stack([rep.fuse_positions(x, 0.2, 0.05, 1.0) for x in (a, b)])
    torch.testing.assert_close(both, want, atol=1e-12, rtol=0)
    empty = rep.fuse_positions(torch.zeros(0, 6, rep.FEATURE_DIM), 0.2)
    assert empty.shape == (0, 6, rep.FEATURE_DIM)


def test_fuse_positions_keeps_the_dtype_and_solves_in_float64():
    """float32 features come back float32, solved in float64: the same numbers as fusing
    their float64 copy and rounding once at the end."""
    f32 = _noisy_features(9, seed=4).float()
    out = rep.fuse_positions(f32, 0.1, 0.02, 0.5)
    assert out.dtype == torch.float32
    assert torch.equal(out, rep.fuse_positions(f32.double(), 0.1, 0.02, 0.5).float())


# ------------------------------------------------------------------ normaliser
def test_normalizer_defaults_and_any_leading_shape():
    gen = torch.Generator().manual_seed(0)
    f = torch.randn(3, 40, rep.FEATURE_DIM, generator=gen)
    f[..., 5] = 2.5  # a constant dimension: std floored at min_std = 1e-2 by default
    norm = rep.Normalizer.fit(f)
    flat = rep.Normalizer.fit(f.reshape(-1, rep.FEATURE_DIM))
    assert torch.equal(norm.mean, flat.mean) and torch.equal(norm.std, flat.std)
    assert norm.mean.shape == norm.std.shape == (rep.FEATURE_DIM,)
    assert norm.std[5] == torch.tensor(1e-2) and norm.mean[5] == 2.5
    want = f.reshape(-1, rep.FEATURE_DIM).double().std(0).float()
    assert torch.allclose(norm.std[:5], want[:5])  # unit-variance data: no floor
    assert torch.equal(norm.mean[rep.CONTACT], torch.zeros(4))
    assert torch.equal(norm.std[rep.CONTACT], torch.ones(4))


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float64])
def test_normalizer_keeps_the_input_dtype(dtype):
    norm = rep.Normalizer(torch.full((rep.FEATURE_DIM,), 0.5), torch.full((rep.FEATURE_DIM,), 2.0))
    x = torch.linspace(-3, 3, rep.FEATURE_DIM, dtype=dtype)
    z = norm.normalize(x)
    assert z.dtype == dtype
    assert torch.equal(z, (x - 0.5) / 2.0)
    back = norm.denormalize(z)
    assert back.dtype == dtype
    assert torch.equal(back, z * 2.0 + 0.5)


def test_normalizer_load_rejects_other_files(tmp_path):
    from safetensors.torch import save_file

    good = {"mean": torch.zeros(rep.FEATURE_DIM), "std": torch.ones(rep.FEATURE_DIM)}
    bad = {
        "extra": {**good, "other": torch.zeros(1)},
        "short": {"mean": torch.zeros(10), "std": torch.ones(10)},
    }
    for name, tensors in bad.items():
        path = tmp_path / f"{name}.safetensors"
        save_file(tensors, str(path))
        with pytest.raises(ValueError, match=r"^.*\.safetensors: not a umf normaliser file$"):
            rep.Normalizer.load(path)
    save_file(good, str(tmp_path / "good.safetensors"))
    assert torch.equal(rep.Normalizer.load(tmp_path / "good.safetensors").std, good["std"])


def test_shift_in_time_holds_the_first_or_last_pose_still_and_keeps_the_length(real_joints):
    f = rep.assemble_features(real_joints, rep.joints_to_rot6d(real_joints))  # (T - 1, 262)
    n = f.shape[0]
    later = rep.shift_in_time(f, 7)
    assert later.shape == f.shape
    torch.testing.assert_close(later[7:], f[:-7])  # the motion, 7 frames on
    for t in range(7):  # before it: the first pose, standing still
        torch.testing.assert_close(later[t, rep.POS], f[0, rep.POS])
        torch.testing.assert_close(later[t, rep.ROT], f[0, rep.ROT])
        assert float(later[t, rep.VEL].abs().max()) == 0.0
    earlier = rep.shift_in_time(f, -5)
    torch.testing.assert_close(earlier[: n - 6], f[5:-1])
    torch.testing.assert_close(earlier[n - 6 :, rep.POS], f[-1:, rep.POS].expand(6, -1))
    assert float(earlier[n - 6 :, rep.VEL].abs().max()) == 0.0  # nothing moves after the end
    torch.testing.assert_close(rep.shift_in_time(f, 0), f)
    torch.testing.assert_close(rep.shift_in_time(f, 10 * n)[-1, rep.POS], f[0, rep.POS])  # clamped
    # held frames are still, so the decoded joints do not move there
    j = rep.features_to_joints(later)
    assert float((j[1:7] - j[:6]).abs().max()) < 1e-6


def test_hold_to_length_cuts_or_holds_the_last_pose(real_joints):
    f = rep.assemble_features(real_joints, rep.joints_to_rot6d(real_joints))
    n = f.shape[0]
    torch.testing.assert_close(rep.hold_to_length(f, n - 10), f[: n - 10])
    longer = rep.hold_to_length(f, n + 8)
    assert longer.shape == (n + 8, f.shape[1])
    torch.testing.assert_close(longer[: n - 1], f[:-1])
    torch.testing.assert_close(longer[n - 1 :, rep.ROT], f[-1:, rep.ROT].expand(9, -1))
    assert float(longer[n - 1 :, rep.VEL].abs().max()) == 0.0


def test_pin_floor_start_moves_the_whole_body_to_start_over_the_origin():
    """One floor shift per row: the first-frame pelvis over the origin (x, z), heights, the
    body relative to its pelvis, the path's shape and every other slot unchanged."""
    f = torch.stack([_noisy_features(9, seed=4), _noisy_features(9, seed=5)])
    f[..., rep.POS] += torch.tensor([1.5, 0.0, -2.0]).repeat(22)  # far from the origin
    out = rep.pin_floor_start(f)
    j, j0 = rep.features_to_joints(out), rep.features_to_joints(f)
    assert torch.allclose(j[:, 0, 0, [0, 2]], torch.zeros(2, 2, dtype=j.dtype), atol=1e-12)
    shift = j0 - j
    assert torch.allclose(shift, shift[:, :1, :1].expand_as(shift), atol=1e-12)  # rigid
    assert torch.equal(shift[..., 1], torch.zeros_like(shift[..., 1]))  # heights kept
    assert torch.equal(out[..., rep.VEL.start :], f[..., rep.VEL.start :])
    assert torch.allclose(rep.pin_floor_start(out), out, atol=1e-12)  # pinned stays put
