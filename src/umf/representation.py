"""The unified 262-number per-person motion feature (InterHuman / InterGen layout).

Per frame t of a person:

=========  ===============================================================
[0:66]     global joint positions (22 x 3), metres, Y up
[66:132]   joint velocities: positions[t + 1] - positions[t] (22 x 3)
[132:258]  local 6-D rotations of the 21 non-root joints (21 x 6)
[258:262]  foot contacts: l_ankle, l_foot, r_ankle, r_foot (0/1)
=========  ===============================================================

As in InterGen, T joint frames give T - 1 feature frames (the velocity of the last
frame is unknown). Scenes are *non-canonical*: everybody is expressed in person 1's
canonical frame (person 1's first-frame pelvis above the origin, feet on the floor,
facing +Z) and every other person keeps their real placement relative to person 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from umf.rotations import matrix_to_6d, sixd_to_matrix, yaw_matrix
from umf.skeleton import (
    FACE_JOINTS,
    FOOT_LEFT,
    FOOT_RIGHT,
    MIRROR_PERM,
    NUM_JOINTS,
    inverse_kinematics,
)

Tensor = torch.Tensor

FEATURE_DIM = 262
POS = slice(0, 66)
VEL = slice(66, 132)
ROT = slice(132, 258)
CONTACT = slice(258, 262)

CONTACT_VELOCITY_THRESHOLD = 0.001  # squared per-frame displacement, m^2
CONTACT_HEIGHT_THRESHOLDS = (0.12, 0.05)  # ankle, toe (m)


# --------------------------------------------------------------------- pieces
def foot_contacts(joints: Tensor) -> Tensor:
    """Contact labels (T - 1, 4) from joints (T, 22, 3), InterGen's rule."""
    out = []
    for foot in (FOOT_LEFT, FOOT_RIGHT):
        idx = list(foot)
        disp2 = ((joints[..., 1:, idx, :] - joints[..., :-1, idx, :]) ** 2).sum(-1)
        height = joints[..., :-1, idx, 1]
        thr = torch.tensor(CONTACT_HEIGHT_THRESHOLDS, dtype=joints.dtype, device=joints.device)
        out.append((disp2 < CONTACT_VELOCITY_THRESHOLD) & (height < thr))
    return torch.cat(out, dim=-1).to(joints.dtype)


def facing_direction(joints: Tensor) -> Tensor:
    """Unit horizontal facing direction (..., 3) from hips and shoulders."""
    r_hip, l_hip, r_sh, l_sh = FACE_JOINTS
    across = (joints[..., r_hip, :] - joints[..., l_hip, :]) + (
        joints[..., r_sh, :] - joints[..., l_sh, :]
    )
    up = torch.zeros_like(across)
    up[..., 1] = 1.0
    fwd = torch.cross(up, across, dim=-1)
    fwd[..., 1] = 0.0
    return fwd / fwd.norm(dim=-1, keepdim=True).clamp_min(1e-8)


def heading_angle(joints: Tensor) -> Tensor:
    """Yaw (rad) of the facing direction, 0 when facing +Z, positive towards +X."""
    f = facing_direction(joints)
    return torch.atan2(f[..., 0], f[..., 2])


@dataclass(frozen=True)
class RigidTransform:
    """x' = R_y(yaw) @ (x - origin): the map into a canonical frame (yaw about +Y)."""

    yaw: float
    origin: tuple[float, float, float]

    def apply(self, joints: Tensor) -> Tensor:
        rot = yaw_matrix(torch.tensor(self.yaw, dtype=joints.dtype)).to(joints.device)
        origin = torch.tensor(self.origin, dtype=joints.dtype, device=joints.device)
        return (joints - origin) @ rot.T

    def invert(self, joints: Tensor) -> Tensor:
        rot = yaw_matrix(torch.tensor(self.yaw, dtype=joints.dtype)).to(joints.device)
        origin = torch.tensor(self.origin, dtype=joints.dtype, device=joints.device)
        return joints @ rot + origin


def canonical_transform(joints: Tensor) -> RigidTransform:
    """Transform that puts a person (T, 22, 3) in the canonical frame.

    Floor: the lowest joint over the whole clip goes to y = 0. Origin: the first-frame
    pelvis (XZ). Heading: the first-frame facing direction turns to +Z.
    """
    floor = float(joints[..., 1].min())
    root = joints[0, 0]
    yaw = float(heading_angle(joints[0]))
    # rotating by -yaw about +Y brings the heading to +Z
    return RigidTransform(yaw=-yaw, origin=(float(root[0]), floor, float(root[2])))


def canonicalize_scene(joints: Tensor) -> tuple[Tensor, RigidTransform]:
    """Express a scene (P, T, 22, 3) in person 1's canonical frame."""
    tf = canonical_transform(joints[0])
    return tf.apply(joints), tf


def mirror_joints(joints: Tensor) -> Tensor:
    """Left/right mirror: negate X and swap left and right joints."""
    out = joints[..., list(MIRROR_PERM), :].clone()
    out[..., 0] = -out[..., 0]
    return out


# --------------------------------------------------------------------- features
def joints_to_features(joints: Tensor, local_rot: Tensor | None = None) -> Tensor:
    """Joints (T, 22, 3) (+ local rotations (T, 22, 3, 3) when known) -> (T - 1, 262).

    Without rotations they are recovered by inverse kinematics against offsets fitted to
    this person (see :mod:`umf.skeleton`).
    """
    _check_joints(joints)
    if local_rot is None:
        local_rot = inverse_kinematics(joints)
    return assemble_features(joints, matrix_to_6d(local_rot[:, 1:]))


def joints_to_rot6d(joints: Tensor) -> Tensor:
    """Local 6-D rotations (T, 21, 6) of joints 1..21 by inverse kinematics.

    They do not change when a person is moved or turned on the floor, so a corpus
    computes them once per clip and reuses them for every placement.
    """
    _check_joints(joints)
    return matrix_to_6d(inverse_kinematics(joints)[:, 1:])


def assemble_features(joints: Tensor, rot6d: Tensor) -> Tensor:
    """Joints (T, 22, 3) and local 6-D rotations (T, 21, 6) -> features (T - 1, 262)."""
    _check_joints(joints)
    t = joints.shape[0] - 1
    pos = joints[:-1].reshape(t, 66)
    vel = (joints[1:] - joints[:-1]).reshape(t, 66)
    rot = rot6d[:-1].reshape(t, 126).to(joints.dtype)
    return torch.cat([pos, vel, rot, foot_contacts(joints)], dim=-1)


def transform_features(features: Tensor, tf: RigidTransform, inverse: bool = False) -> Tensor:
    """Move features (..., T, 262) rigidly: into ``tf``'s frame, or back out with ``inverse``.

    Positions move as points, velocities turn as vectors; local rotations of joints 1..21
    and foot contacts do not change under a turn about +Y and a shift.
    """
    lead = features.shape[:-1]
    pos = features[..., POS].reshape(*lead, NUM_JOINTS, 3)
    vel = features[..., VEL].reshape(*lead, NUM_JOINTS, 3)
    rot = yaw_matrix(torch.tensor(tf.yaw, dtype=features.dtype)).to(features.device)
    if inverse:
        pos, vel = tf.invert(pos), vel @ rot
    else:
        pos, vel = tf.apply(pos), vel @ rot.T
    rest = features[..., VEL.stop :]
    return torch.cat([pos.reshape(*lead, 66), vel.reshape(*lead, 66), rest], dim=-1)


def mirror_rot6d(rot6d: Tensor) -> Tensor:
    """Mirror local 6-D rotations (..., 21, 6): conjugate by diag(-1, 1, 1), swap sides."""
    rot = sixd_to_matrix(rot6d)
    m = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=rot6d.dtype))
    perm = [p - 1 for p in MIRROR_PERM[1:]]
    return matrix_to_6d((m @ rot @ m)[..., perm, :, :])


def _check_joints(joints: Tensor) -> None:
    if joints.ndim != 3 or joints.shape[-2:] != (NUM_JOINTS, 3):
        raise ValueError(f"expected joints (T, 22, 3), got {tuple(joints.shape)}")
    if joints.shape[0] < 2:
        raise ValueError("need at least 2 frames to compute velocities")


def features_to_joints(features: Tensor) -> Tensor:
    """(..., T, 262) -> global joints (..., T, 22, 3) (the position slots)."""
    return features[..., POS].reshape(*features.shape[:-1], NUM_JOINTS, 3)


def features_to_joints_integrated(features: Tensor) -> Tensor:
    """Joints (..., T + 1, 22, 3): positions plus one more frame from the last velocity."""
    pos = features_to_joints(features)
    last = pos[..., -1:, :, :] + features[..., -1:, VEL].reshape(*pos.shape[:-3], 1, 22, 3)
    return torch.cat([pos, last], dim=-3)


def _fuse(pos: Tensor, vel: Tensor, weight: float) -> Tensor:
    """argmin_P weight * |P - pos|^2 + |diff(P) - vel[:-1]|^2 over time (axis -2), float64."""
    t = pos.shape[-2]
    diff = torch.zeros(t - 1, t, dtype=torch.float64, device=pos.device)
    idx = torch.arange(t - 1, device=pos.device)
    diff[idx, idx], diff[idx, idx + 1] = -1.0, 1.0
    system = weight * torch.eye(t, dtype=torch.float64, device=pos.device) + diff.T @ diff
    return torch.linalg.solve(system, weight * pos + diff.T @ vel[..., :-1, :])


def fuse_positions(features: Tensor, position_weight: float, root_weight: float | None = None,
                   height_weight: float | None = None) -> Tensor:  # fmt: skip
    """Make positions and velocities of decoded features (..., T, 262) agree.

    The feature is over-complete: positions and frame-to-frame velocities describe the
    same motion twice. A decoder predicts each with its own small frame-to-frame noise,
    and the noise in positions is what shows (a body that shakes by centimetres every
    frame, a standing person whose pelvis wanders). The fused positions P minimise, per
    coordinate,

        weight * sum_t |P_t - P^_t|^2 + sum_t |P_{t+1} - P_t - V^_t|^2,

    following the predicted velocities from frame to frame and the predicted positions
    over longer spans (no drift). The pelvis's floor path (x, z) uses ``root_weight``
    (default: the same), its height ``height_weight`` (default: ``root_weight``), the
    joints relative to the pelvis ``position_weight``: a smaller root weight trusts the
    velocities longer, where the absolute path is noisiest. The velocity slots become the
    fused differences. Tridiagonal systems of T unknowns, one solve each.
    """
    t = features.shape[-2]
    if position_weight <= 0 or t < 2:
        return features
    root_weight = position_weight if root_weight is None else root_weight
    height_weight = root_weight if height_weight is None else height_weight
    lead = features.shape[:-1]
    pos = features[..., POS].to(torch.float64).reshape(*lead, NUM_JOINTS, 3)
    vel = features[..., VEL].to(torch.float64).reshape(*lead, NUM_JOINTS, 3)
    root, root_vel = pos[..., :1, :], vel[..., :1, :]
    flat = (*lead[:-1], t, NUM_JOINTS * 3)  # explicit sizes: an empty batch stays empty
    rel = _fuse((pos - root).reshape(flat), (vel - root_vel).reshape(flat), position_weight)
    path = _fuse(root.reshape(*flat[:-1], 3), root_vel.reshape(*flat[:-1], 3), root_weight)
    if height_weight != root_weight:  # not in place: losses differentiate through it
        height = _fuse(root[..., 1], root_vel[..., 1], height_weight)
        path = torch.cat([path[..., :1], height, path[..., 2:]], dim=-1)
    fused = (rel.reshape(pos.shape) + path.reshape(root.shape)).reshape(*lead, 66)
    vel = features[..., VEL].to(torch.float64)
    new_vel = torch.cat([fused[..., 1:, :] - fused[..., :-1, :], vel[..., -1:, :]], dim=-2)
    rest = features[..., VEL.stop :]
    dtype = features.dtype
    return torch.cat([fused.to(dtype), new_vel.to(dtype), rest], dim=-1)


def floor_start(features: Tensor) -> Tensor:
    """(..., 2) the pelvis's first-frame floor position (x, z) in m, for features (..., T, 262),
    in their frame: for people 2..N, person 1's (+x: person 1's left)."""
    return features[..., 0, POS][..., [0, 2]]  # the pelvis is joint 0


def pin_floor_start(features: Tensor) -> Tensor:
    """Features (..., T, 262) moved on the floor (every joint, every frame, by one shift
    per row) so that the first-frame pelvis stands over the origin: where the canonical
    frame puts person 1 of every training crop (:func:`canonicalize_features`). The fused
    floor path (:func:`fuse_positions` at a small root weight) follows the decoded
    velocities and sits where the decoded positions do on average; where the two disagree
    (a generated runner's positions travel half as far as its legs), the average leaves
    the start a metre or more from the origin, and people placed relative to it out of
    place. Velocities and everything else are unchanged."""
    start = floor_start(features)
    return place_features(features, 0.0, -start[..., 0], -start[..., 1])


def features_to_local_rotations(features: Tensor) -> Tensor:
    """(..., T, 262) -> local rotation matrices (..., T, 21, 3, 3) of joints 1..21."""
    d6 = features[..., ROT].reshape(*features.shape[:-1], NUM_JOINTS - 1, 6)
    return sixd_to_matrix(d6)


def mirror_features(features: Tensor) -> Tensor:
    """Mirror features left/right without going back to joints.

    Positions and velocities: negate X and swap sides. Rotations: conjugate by the
    reflection M = diag(-1, 1, 1) (R' = M R M) and swap sides. Contacts: swap feet.
    """
    *lead, _ = features.shape
    pos = mirror_joints(features[..., POS].reshape(*lead, NUM_JOINTS, 3))
    vel = mirror_joints(features[..., VEL].reshape(*lead, NUM_JOINTS, 3))
    rot = mirror_rot6d(features[..., ROT].reshape(*lead, NUM_JOINTS - 1, 6))
    contacts = features[..., CONTACT][..., [2, 3, 0, 1]]
    return torch.cat(
        [
            pos.reshape(*lead, 66),
            vel.reshape(*lead, 66),
            rot.reshape(*lead, 126),
            contacts,
        ],
        dim=-1,
    )


# --------------------------------------------------------------------- normaliser
@dataclass
class Normalizer:
    """Per-dimension mean / std over a training corpus, saved with the model."""

    mean: Tensor
    std: Tensor

    @classmethod
    def fit(cls, features: Tensor, min_std: float = 1e-2) -> Normalizer:
        """From stacked feature frames (N, 262). Contacts stay unscaled (0/1 labels)."""
        flat = features.reshape(-1, features.shape[-1]).double()
        mean = flat.mean(0)
        std = flat.std(0).clamp_min(min_std)
        mean[CONTACT] = 0.0
        std[CONTACT] = 1.0
        return cls(mean.float(), std.float())

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.mean.to(x)) / self.std.to(x)

    def denormalize(self, x: Tensor) -> Tensor:
        return x * self.std.to(x) + self.mean.to(x)

    def save(self, path) -> None:
        from umf.io import save_tensors_atomic

        save_tensors_atomic({"mean": self.mean, "std": self.std}, path)

    @classmethod
    def load(cls, path) -> Normalizer:
        from safetensors.torch import load_file

        d = load_file(str(path))
        if set(d) != {"mean", "std"} or d["mean"].shape != (FEATURE_DIM,):
            raise ValueError(f"{path}: not a umf normaliser file")
        return cls(d["mean"], d["std"])


def place_features(features: Tensor, yaw: float | Tensor, dx: float | Tensor,
                   dz: float | Tensor) -> Tensor:  # fmt: skip
    """Turn people about +Y by ``yaw`` (rad) around the origin, then move them by (dx, dz):
    numbers, or tensors of the leading shape (...,) for one move per row.

    Only positions and velocities change: local rotations exclude the root and contacts
    depend on heights and speeds, both invariant to a rigid motion on the floor. Same
    convention as :func:`umf.data.scenes.yaw_rotate` (+Z turns to (sin, 0, cos)).
    Works on (..., T, 262) and matches features recomputed from the moved joints.
    """
    lead = features.shape[:-1]
    rot = yaw_matrix(torch.as_tensor(yaw, dtype=features.dtype)).to(features.device)
    dx, dz = (torch.as_tensor(v, dtype=features.dtype, device=features.device) for v in (dx, dz))
    shift = torch.stack([dx, torch.zeros_like(dx), dz], dim=-1)[..., None, None, :]
    pos = features[..., POS].reshape(*lead, 22, 3) @ rot.T + shift
    vel = features[..., VEL].reshape(*lead, 22, 3) @ rot.T
    return torch.cat(
        [pos.reshape(*lead, 66), vel.reshape(*lead, 66), features[..., VEL.stop :]], dim=-1
    )


def shift_in_time(features: Tensor, frames: int) -> Tensor:
    """``features`` (T, 262) later by ``frames`` (earlier where negative), the length kept:
    the first (last) pose held still before the motion begins (after it ends), its
    velocities zero there. A person who waits before acting (an answer to a bow)."""
    n = features.shape[0]
    frames = max(-(n - 1), min(n - 1, int(frames)))
    if frames < 0:
        return hold_to_length(features[-frames:], n)
    first = features[:1].clone()
    first[:, VEL] = 0.0  # the held pose does not move until the motion begins
    return torch.cat([first.expand(frames, -1), features[: n - frames]])


def hold_to_length(features: Tensor, frames: int) -> Tensor:
    """``features`` (T, 262) cut to ``frames``, or carried on to it by holding the last pose
    still (velocities zero from the last frame on: nothing moves after it)."""
    if features.shape[0] >= frames:
        return features[:frames].clone()
    last = features[-1:].clone()
    last[:, VEL] = 0.0
    return torch.cat([features[:-1], last.expand(frames - features.shape[0] + 1, -1)])


def leader_frame(features: Tensor) -> RigidTransform:
    """The map (a turn about +Y and a shift on the floor, heights kept) that puts one
    person's features (T, 262) where :func:`canonicalize_features` puts person 1 of a
    training crop: first-frame pelvis over the origin, first-frame facing along +Z."""
    joints0 = features_to_joints(features[0])
    root = joints0[0]
    return RigidTransform(yaw=-float(heading_angle(joints0)),
                          origin=(float(root[0]), 0.0, float(root[2])))  # fmt: skip


def canonicalize_features(features: Tensor) -> Tensor:
    """Express people (P, T, 262) (or one person (T, 262)) in person 1's frame at frame 0.

    Person 1's first-frame pelvis goes over the origin (XZ only; heights are kept) and
    person 1's first-frame facing direction turns to +Z; everyone moves with them, so
    relative placements are unchanged.
    """
    first = features if features.ndim == 2 else features[0]
    joints0 = features_to_joints(first[0])
    yaw = -heading_angle(joints0)
    rot = yaw_matrix(yaw)
    origin = torch.stack([joints0[0, 0], joints0.new_zeros(()), joints0[0, 2]])
    shift = -(rot @ origin)
    return place_features(features, yaw, float(shift[0]), float(shift[2]))
