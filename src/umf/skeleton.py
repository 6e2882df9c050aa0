"""The SMPL-22 skeleton: names, hierarchy, rest offsets, forward and inverse kinematics.

Y is up, metres, a person in the rest pose stands at the origin facing +Z, so the
person's left is +X. The rest pose is a T-pose (arms along +-X); rest *directions* are
fixed here, bone *lengths* come from data (:func:`fit_offsets`) or the default body
(:data:`DEFAULT_OFFSETS`, the Bandai actors' skeleton after retargeting).

Inverse kinematics recovers local rotations from joint positions: swing-only for
single-child bones (twist about a bone is not observable from positions) and a full
frame for the two branching joints (pelvis, spine3). Forward kinematics of the result
with the fitted offsets reproduces the input joints of a rigid skeleton exactly.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from umf.rotations import quat_between, quat_to_matrix

Tensor = torch.Tensor

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "l_hip", "r_hip", "spine1", "l_knee", "r_knee", "spine2", "l_ankle",
    "r_ankle", "spine3", "l_foot", "r_foot", "neck", "l_collar", "r_collar", "head",
    "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist",
)  # fmt: skip
NUM_JOINTS = 22
PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19,
)  # fmt: skip
# HumanML3D kinematic chains (drawing order of the stick figure)
CHAINS: tuple[tuple[int, ...], ...] = (
    (0, 2, 5, 8, 11),
    (0, 1, 4, 7, 10),
    (0, 3, 6, 9, 12, 15),
    (9, 14, 17, 19, 21),
    (9, 13, 16, 18, 20),
)
FOOT_LEFT = (7, 10)
FOOT_RIGHT = (8, 11)
FACE_JOINTS = (2, 1, 17, 16)  # r_hip, l_hip, r_shoulder, l_shoulder
# left <-> right permutation used by mirroring
MIRROR_PERM: tuple[int, ...] = tuple(
    JOINT_NAMES.index(n.replace("l_", "#").replace("r_", "l_").replace("#", "r_"))
    for n in JOINT_NAMES
)
CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(c for c, p in enumerate(PARENTS) if p == j) for j in range(NUM_JOINTS)
)

# Unit rest direction of each joint's offset from its parent (T-pose, facing +Z).
REST_DIRECTIONS: tuple[tuple[float, float, float], ...] = (
    (0, 0, 0),    # pelvis (root)
    (1, 0, 0),    # l_hip   (pelvis -> l_hip; real hips also sit a little lower)
    (-1, 0, 0),   # r_hip
    (0, 1, 0),    # spine1
    (0, -1, 0),   # l_knee
    (0, -1, 0),   # r_knee
    (0, 1, 0),    # spine2
    (0, -1, 0),   # l_ankle
    (0, -1, 0),   # r_ankle
    (0, 1, 0),    # spine3
    (0, 0, 1),    # l_foot (toes forward)
    (0, 0, 1),    # r_foot
    (0, 1, 0),    # neck
    (1, 0, 0),    # l_collar
    (-1, 0, 0),   # r_collar
    (0, 1, 0),    # head
    (1, 0, 0),    # l_shoulder
    (-1, 0, 0),   # r_shoulder
    (1, 0, 0),    # l_elbow
    (-1, 0, 0),   # r_elbow
    (1, 0, 0),    # l_wrist
    (-1, 0, 0),   # r_wrist
)  # fmt: skip

# Rest offsets (m) of the default body: the Bandai actors' skeleton after retargeting to
# SMPL-22 (`fit_offsets` gives the same values, to 1e-8 m, on all 3,076 clips: the
# dataset is retargeted to one character), left/right symmetrised. Used by exports/demo.
DEFAULT_OFFSETS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),  # pelvis
    (0.0647, -0.0219, 0.0),  # l_hip
    (-0.0647, -0.0219, 0.0),  # r_hip
    (0.0, 0.1574, 0.0),  # spine1
    (0.0, -0.3908, 0.0),  # l_knee
    (0.0, -0.3908, 0.0),  # r_knee
    (0.0, 0.0899, 0.0),  # spine2
    (0.0, -0.4099, 0.0),  # l_ankle
    (0.0, -0.4099, 0.0),  # r_ankle
    (0.0, 0.0819, 0.0),  # spine3
    (0.0, 0.0, 0.1175),  # l_foot
    (0.0, 0.0, 0.1175),  # r_foot
    (0.0, 0.0819, 0.0),  # neck
    (0.0498, 0.0481, -0.0024),  # l_collar
    (-0.0498, 0.0481, -0.0024),  # r_collar
    (0.0, 0.0646, 0.0),  # head
    (0.0535, 0.0, 0.0),  # l_shoulder
    (-0.0535, 0.0, 0.0),  # r_shoulder
    (0.2433, 0.0, 0.0),  # l_elbow
    (-0.2433, 0.0, 0.0),  # r_elbow
    (0.2229, 0.0, 0.0),  # l_wrist
    (-0.2229, 0.0, 0.0),  # r_wrist
)

# Branching joints get a full frame from two of their children: (up child, left, right).
_BRANCH_FRAMES: dict[int, tuple[int, int, int]] = {0: (3, 1, 2), 9: (12, 13, 14)}


def rest_directions(dtype=torch.float32, device=None) -> Tensor:
    return torch.tensor(REST_DIRECTIONS, dtype=dtype, device=device)


def default_offsets(dtype=torch.float32, device=None) -> Tensor:
    """Rest offsets (22, 3) of the default body (T-pose, facing +Z)."""
    return torch.tensor(DEFAULT_OFFSETS, dtype=dtype, device=device)


def bone_lengths(joints: Tensor) -> Tensor:
    """Per-frame bone lengths (..., 22); entry 0 (root) is 0."""
    parents = torch.tensor(PARENTS[1:], device=joints.device)
    lengths = (joints[..., 1:, :] - joints[..., parents, :]).norm(dim=-1)
    return torch.cat([torch.zeros_like(lengths[..., :1]), lengths], dim=-1)


# --------------------------------------------------------------------- FK
def forward_kinematics(local_rot: Tensor, root_pos: Tensor, offsets: Tensor) -> Tensor:
    """Joint positions from local rotation matrices.

    Args:
        local_rot: (..., 22, 3, 3) rotation of each joint relative to its parent
            (joint 0: global root orientation).
        root_pos: (..., 3) pelvis position.
        offsets: (22, 3) or (..., 22, 3) rest offsets from each parent.
    Returns:
        (..., 22, 3) global joint positions.
    """
    offsets = offsets.to(local_rot.dtype).expand(*local_rot.shape[:-3], NUM_JOINTS, 3)
    glob_rot: list[Tensor] = [local_rot[..., 0, :, :]]
    pos: list[Tensor] = [root_pos]
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        pos.append(pos[p] + (glob_rot[p] @ offsets[..., j, :, None])[..., 0])
        glob_rot.append(glob_rot[p] @ local_rot[..., j, :, :])
    return torch.stack(pos, dim=-2)


def global_rotations(local_rot: Tensor) -> Tensor:
    glob: list[Tensor] = [local_rot[..., 0, :, :]]
    for j in range(1, NUM_JOINTS):
        glob.append(glob[PARENTS[j]] @ local_rot[..., j, :, :])
    return torch.stack(glob, dim=-3)


# --------------------------------------------------------------------- IK
def _frame(up: Tensor, across: Tensor) -> Tensor:
    """Orthonormal frame with columns (x=across, y=up, z=x cross y); up wins ties."""
    y = F.normalize(up, dim=-1, eps=1e-8)
    x = across - (across * y).sum(-1, keepdim=True) * y
    x = F.normalize(x, dim=-1, eps=1e-8)
    z = torch.cross(x, y, dim=-1)
    return torch.stack([x, y, z], dim=-1)


def _branch_frame(vectors: Tensor, joint: int) -> Tensor:
    """Frame of a branching joint from child offsets ``vectors`` (..., 22, 3)."""
    up, left, right = _BRANCH_FRAMES[joint]
    return _frame(vectors[..., up, :], vectors[..., left, :] - vectors[..., right, :])


def fit_offsets(joints: Tensor) -> Tensor:
    """Rest offsets (22, 3) that make FK(IK(joints)) reproduce ``joints``.

    ``joints`` is (T, 22, 3) (or (..., T, 22, 3), averaged over all leading axes).
    Single-child bones keep the canonical T-pose direction with the mean bone length;
    children of the branching joints keep their mean offset in the joint's own frame.
    """
    flat = joints.reshape(-1, NUM_JOINTS, 3)
    parents = torch.tensor(PARENTS[1:], device=joints.device)
    vec = torch.cat([torch.zeros_like(flat[:, :1]), flat[:, 1:] - flat[:, parents]], dim=1)
    offsets = rest_directions(joints.dtype, joints.device) * vec.norm(dim=-1).mean(0)[:, None]
    for joint, (up, left, right) in _BRANCH_FRAMES.items():
        frame = _branch_frame(vec, joint)  # (F, 3, 3) world <- joint frame
        for child in (up, left, right):
            local = (frame.transpose(-1, -2) @ vec[:, child, :, None])[..., 0]
            offsets[child] = local.mean(0)
    return offsets


def inverse_kinematics(joints: Tensor, offsets: Tensor | None = None) -> Tensor:
    """Local rotation matrices (..., 22, 3, 3) from joint positions (..., 22, 3).

    ``offsets`` are the rest offsets the rotations are relative to: (22, 3), or one set per
    leading index broadcast against ``joints`` (``(N, 1, 22, 3)`` for N people's (N, T, 22,
    3): everybody in one call, which a GPU needs; default: fitted from ``joints``
    themselves). Leaf joints (feet, head, wrists) get the identity.
    """
    if offsets is None:
        offsets = fit_offsets(joints)
    offsets = offsets.to(joints.dtype)
    parents = torch.tensor(PARENTS[1:], device=joints.device)
    vec = torch.cat(
        [torch.zeros_like(joints[..., :1, :]), joints[..., 1:, :] - joints[..., parents, :]],
        dim=-2,
    )
    eye = torch.eye(3, dtype=joints.dtype, device=joints.device)
    glob: list[Tensor | None] = [None] * NUM_JOINTS
    local: list[Tensor | None] = [None] * NUM_JOINTS
    for j in range(NUM_JOINTS):
        parent_glob = glob[PARENTS[j]] if j > 0 else eye.expand(*joints.shape[:-2], 3, 3)
        if j in _BRANCH_FRAMES:
            actual = _branch_frame(vec, j)
            rest = _branch_frame(offsets.expand_as(vec), j)
            g = actual @ rest.transpose(-1, -2)
        elif len(CHILDREN[j]) == 1:
            c = CHILDREN[j][0]
            target = (parent_glob.transpose(-1, -2) @ vec[..., c, :, None])[..., 0]
            lrot = quat_to_matrix(quat_between(offsets[..., c, :].expand_as(target), target))
            g = parent_glob @ lrot
        else:  # leaf
            g = parent_glob
        glob[j] = g
        local[j] = g if j == 0 else parent_glob.transpose(-1, -2) @ g
    return torch.stack(local, dim=-3)  # type: ignore[arg-type]
