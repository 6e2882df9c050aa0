import itertools

import torch

from umf import skeleton as S
from umf.rotations import axis_angle_to_matrix


def test_hierarchy_is_consistent():
    assert len(S.JOINT_NAMES) == len(S.PARENTS) == len(S.REST_DIRECTIONS) == 22
    assert all(p < j for j, p in enumerate(S.PARENTS))  # parents come first
    for chain in S.CHAINS:
        for parent, child in itertools.pairwise(chain):
            assert S.PARENTS[child] == parent
    # mirroring swaps names and is an involution
    for j, m in enumerate(S.MIRROR_PERM):
        assert S.MIRROR_PERM[m] == j
        assert S.JOINT_NAMES[j].replace("l_", "r_") == S.JOINT_NAMES[m].replace("l_", "r_")
    # the person's left is +X when facing +Z
    off = S.default_offsets()
    assert off[S.JOINT_NAMES.index("l_hip"), 0] > 0 > off[S.JOINT_NAMES.index("r_hip"), 0]


def test_fk_identity_is_rest_pose():
    off = S.default_offsets(torch.float64)
    rot = torch.eye(3, dtype=torch.float64).expand(22, 3, 3)
    j = S.forward_kinematics(rot, torch.zeros(3, dtype=torch.float64), off)
    # walking up the parents sums the offsets
    for k in range(22):
        expect, p = torch.zeros(3, dtype=torch.float64), k
        while p >= 0:
            expect += off[p]
            p = S.PARENTS[p]
        assert torch.allclose(j[k], expect)


def test_fk_rotating_root_rotates_everything():
    off = S.default_offsets(torch.float64)
    rot = torch.eye(3, dtype=torch.float64).repeat(22, 1, 1)
    base = S.forward_kinematics(rot, torch.zeros(3, dtype=torch.float64), off)
    r = axis_angle_to_matrix(torch.tensor([0.3, -1.1, 0.4], dtype=torch.float64))
    rot[0] = r
    turned = S.forward_kinematics(rot, torch.zeros(3, dtype=torch.float64), off)
    assert torch.allclose(turned, base @ r.T)


def test_ik_fk_round_trip_synthetic():
    torch.manual_seed(0)
    off = S.default_offsets(torch.float64)
    rot = axis_angle_to_matrix(0.6 * torch.randn(50, 22, 3, dtype=torch.float64))
    root = torch.randn(50, 3, dtype=torch.float64)
    joints = S.forward_kinematics(rot, root, off)
    fitted = S.fit_offsets(joints)
    assert torch.allclose(fitted, off, atol=1e-10)
    back = S.forward_kinematics(S.inverse_kinematics(joints, fitted), joints[:, 0], fitted)
    assert (back - joints).abs().max() < 1e-9


def test_ik_fk_round_trip_real_clip(real_joints):
    fitted = S.fit_offsets(real_joints)
    local = S.inverse_kinematics(real_joints, fitted)
    back = S.forward_kinematics(local, real_joints[:, 0], fitted)
    err = (back - real_joints).norm(dim=-1)
    # rigid mocap skeleton: reproduced to well under a millimetre
    assert err.max() < 1e-4, float(err.max())
    # rotations are proper
    det = torch.linalg.det(local)
    assert torch.allclose(det, torch.ones_like(det), atol=1e-9)


def test_ik_detects_wrong_offsets(real_joints):
    """A skeleton with a swapped axis must not reproduce the motion."""
    fitted = S.fit_offsets(real_joints)
    wrong = fitted[:, [2, 1, 0]]
    local = S.inverse_kinematics(real_joints, wrong)
    back = S.forward_kinematics(local, real_joints[:, 0], fitted)
    assert (back - real_joints).norm(dim=-1).max() > 0.05


def test_bone_lengths_constant_on_real_data(real_joints):
    lengths = S.bone_lengths(real_joints)
    assert lengths.shape == (real_joints.shape[0], 22)
    assert (lengths[:, 1:].std(0) < 1e-4).all()
