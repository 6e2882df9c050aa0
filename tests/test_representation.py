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
