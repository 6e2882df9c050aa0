"""The HumanML3D 263-d vector format: joints -> vectors and the exact inverse.

One encoding below both the dataset loader (:mod:`umf.data.humanml3d`) and the exporter
(:mod:`umf.exports.humanml3d`). HumanML3D motion is 20 fps.

Conventions of the 263-d vector (the ones HumanML3D's released files use; ``T`` rows):

=========  ==================================================================
[0:1]      ``theta_vel``: HALF the per-frame turn of the heading quaternion (below)
[1:3]      root XZ velocity ``root[t+1] - root[t]`` rotated by ``r[t+1]``
[3:4]      root height y at frame t
[4:67]     joints 1..21 minus the root's ground point, rotated by ``r[t]``
[67:193]   6-D local rotations of joints 1..21 (first two columns of R)
[193:259]  all 22 joint displacements ``J[t+1] - J[t]`` rotated by ``r[t]``
[259:263]  foot contacts l_ankle, l_foot, r_ankle, r_foot
=========  ==================================================================

The heading quaternion ``r[t]`` (w, x, y, z) is the yaw that turns person's facing
direction onto +Z, i.e. it maps world vectors INTO the heading frame; decoding applies its
conjugate. With ``psi`` the umf yaw of the facing direction (0 facing +Z, positive towards
+X, a right-handed turn about +Y), ``r[t] = (cos(-psi/2), 0, sin(-psi/2), 0)`` and
``theta_vel[t] = -(psi[t+1] - psi[t]) / 2``: a positive value is a turn to the person's
right. Decoding rebuilds ``r[t] = (cos a, 0, sin a, 0)`` with ``a[t] = sum(theta_vel[:t])``,
which assumes ``r[0]`` is the identity: HumanML3D stores every clip canonicalised so the
first frame faces +Z with the root above the origin.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from umf.representation import facing_direction
from umf.rotations import matrix_to_6d, quat_conjugate, quat_mul, quat_rotate, yaw_matrix
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT, NUM_JOINTS, inverse_kinematics

Tensor = torch.Tensor

HUMANML3D_FPS = 20.0
VEC_DIM = 263
ROOT_TURN = slice(0, 1)
ROOT_VEL = slice(1, 3)
ROOT_Y = slice(3, 4)
RIC = slice(4, 67)
ROT = slice(67, 193)
LOCAL_VEL = slice(193, 259)
CONTACT = slice(259, 263)


# HumanML3D's rule: squared per-frame displacement only (its height test is disabled).
CONTACT_VELOCITY_THRESHOLD = 0.002


# --------------------------------------------------------------------- heading
def _yaw_quat(angle: Tensor) -> Tensor:
    """Quaternion (w, x, y, z) of a right-handed rotation by ``angle`` (rad) about +Y."""
    half = 0.5 * angle
    zero = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zero, torch.sin(half), zero], dim=-1)


def _gaussian_smooth(x: Tensor, sigma: float) -> Tensor:
    """Gaussian filter of ``x`` (T, C) along time, edges held (HumanML3D's 'nearest')."""
    radius = max(1, int(4.0 * sigma + 0.5))
    k = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    kernel = torch.exp(-0.5 * (k / sigma) ** 2)
    kernel = (kernel / kernel.sum()).expand(x.shape[1], 1, -1)
    padded = F.pad(x.T[None], (radius, radius), mode="replicate")
    return F.conv1d(padded, kernel, groups=x.shape[1])[0].T


def facing_angles(joints: Tensor, sigma: float = 0.0) -> Tensor:
    """Yaw ``psi`` (T,) of the facing direction (hips + shoulders), optionally smoothed.

    ``sigma`` (frames) smooths the facing vectors before taking the angle; HumanML3D's
    own processing used 20. 0 keeps the raw per-frame facing.
    """
    fwd = facing_direction(joints)
    if sigma > 0:
        fwd = _gaussian_smooth(fwd, sigma)
    return torch.atan2(fwd[..., 0], fwd[..., 2])


def canonicalize_first_frame(joints: Tensor, sigma: float = 0.0) -> Tensor:
    """HumanML3D's canonical frame: first-frame root XZ at the origin, facing +Z.

    Heights are left untouched (no floor shift), so decoding reproduces y exactly.
    """
    psi0 = facing_angles(joints, sigma)[0]
    ground = joints[0, 0] * torch.tensor([1.0, 0.0, 1.0], dtype=joints.dtype)
    return (joints - ground) @ yaw_matrix(-psi0).T


# --------------------------------------------------------------------- encode / decode
def _contacts(joints: Tensor, threshold: float) -> Tensor:
    """(T - 1, 4) contacts from squared per-frame foot displacement."""
    idx = list(FOOT_LEFT + FOOT_RIGHT)
    disp2 = ((joints[1:, idx] - joints[:-1, idx]) ** 2).sum(-1)
    return (disp2 < threshold).to(joints.dtype)


def encode_joints(
    joints: Tensor,
    *,
    heading_sigma: float = 0.0,
    contact_threshold: float = CONTACT_VELOCITY_THRESHOLD,
) -> Tensor:
    """Global joints (T, 22, 3) -> HumanML3D vectors (T - 1, 263), see the module docstring.

    The clip is first put in HumanML3D's canonical frame (:func:`canonicalize_first_frame`),
    so ``recover_joints(encode_joints(J))`` equals that canonical copy of ``J[:-1]``.
    Rotations come from :func:`umf.skeleton.inverse_kinematics` (fitted offsets), so they
    are umf's, not numerically HumanML3D's. Computed in float64, returned in J's dtype.
    """
    if joints.ndim != 3 or tuple(joints.shape[1:]) != (NUM_JOINTS, 3):
        raise ValueError(f"expected joints (T, 22, 3), got {tuple(joints.shape)}")
    if joints.shape[0] < 2:
        raise ValueError("need at least 2 frames")
    j = canonicalize_first_frame(joints.double(), heading_sigma)
    n = j.shape[0] - 1
    q = _yaw_quat(-facing_angles(j, heading_sigma))  # (T, 4): facing -> +Z
    rel = quat_mul(q[1:], quat_conjugate(q[:-1]))
    rel = torch.where(rel[..., :1] < 0, -rel, rel)  # shortest turn, also across +-180 deg
    turn = torch.atan2(rel[..., 2], rel[..., 0])  # half the per-frame turn
    root = j[:, 0]
    root_vel = quat_rotate(q[1:], root[1:] - root[:-1])[:, [0, 2]]
    ground = root * torch.tensor([1.0, 0.0, 1.0], dtype=j.dtype)
    q_joints = q[:, None].expand(-1, NUM_JOINTS - 1, -1)
    ric = quat_rotate(q_joints, j[:, 1:] - ground[:, None])
    rot = matrix_to_6d(inverse_kinematics(j)[:, 1:])
    local_vel = quat_rotate(q[:-1, None].expand(-1, NUM_JOINTS, -1), j[1:] - j[:-1])
    out = torch.cat(
        [
            turn[:, None],
            root_vel,
            root[:-1, 1:2],
            ric[:-1].reshape(n, 63),
            rot[:-1].reshape(n, 126),
            local_vel.reshape(n, 66),
            _contacts(j, contact_threshold),
        ],
        dim=-1,
    )
    return out.to(joints.dtype)


def recover_root(vecs: Tensor) -> tuple[Tensor, Tensor]:
    """Heading quaternions (..., T, 4) and root positions (..., T, 3) from (..., T, 263).

    ``a[t] = sum(theta_vel[:t])`` (frame 0: 0), ``r[t] = (cos a, 0, sin a, 0)``; root XZ at
    t is the sum of the stored velocities of rows < t, each rotated back by ``conj(r)`` of
    the frame it ends in. Computed in float64.
    """
    v = vecs.double()
    turn = v[..., 0]
    angle = torch.cat([torch.zeros_like(turn[..., :1]), turn[..., :-1]], dim=-1).cumsum(-1)
    zero = torch.zeros_like(angle)
    q = torch.stack([torch.cos(angle), zero, torch.sin(angle), zero], dim=-1)
    vel = torch.stack([v[..., :-1, 1], zero[..., 1:], v[..., :-1, 2]], dim=-1)
    vel = torch.cat([torch.zeros_like(vel[..., :1, :]), vel], dim=-2)
    xz = quat_rotate(quat_conjugate(q), vel).cumsum(-2)
    root = torch.stack([xz[..., 0], v[..., 3], xz[..., 2]], dim=-1)
    return q, root


def recover_joints(vecs: Tensor) -> Tensor:
    """HumanML3D vectors (..., T, 263) -> global joints (..., T, 22, 3) in vecs' dtype.

    Un-rotates the heading-aligned positions by ``conj(r[t])`` and adds the root XZ.
    """
    if vecs.shape[-1] != VEC_DIM:
        raise ValueError(f"expected (..., T, {VEC_DIM}) vectors, got {tuple(vecs.shape)}")
    q, root = recover_root(vecs)
    ric = vecs.double()[..., RIC].reshape(*vecs.shape[:-1], NUM_JOINTS - 1, 3)
    q_inv = quat_conjugate(q)[..., None, :].expand(*ric.shape[:-1], 4)
    ground = root * torch.tensor([1.0, 0.0, 1.0], dtype=root.dtype)
    joints = quat_rotate(q_inv, ric) + ground[..., None, :]
    return torch.cat([root[..., None, :], joints], dim=-2).to(vecs.dtype)


# --------------------------------------------------------------------- resampling
def resampled_length(num_frames: int, src_fps: float, dst_fps: float) -> int:
    """Frames of the ``dst_fps`` grid ``k / dst_fps`` inside ``[0, (T - 1) / src_fps]``."""
    if num_frames < 2:
        return num_frames
    return math.floor((num_frames - 1) * dst_fps / src_fps + 1e-9) + 1


def resample(x: Tensor, src_fps: float, dst_fps: float) -> Tensor:
    """Linear interpolation along dim 0 onto the exact time grid ``k / dst_fps``.

    The grid never extrapolates past the last source frame: 20 -> 30 fps gives
    ``floor(1.5 (T - 1)) + 1`` frames, the same duration when T is odd and 1/60 s shorter
    when T is even. Positions that are linear in time stay exact.
    """
    num = x.shape[0]
    if num < 2 or src_fps == dst_fps:
        return x.clone()
    steps = torch.arange(resampled_length(num, src_fps, dst_fps), dtype=torch.float64)
    pos = steps * src_fps / dst_fps  # source frame index (multiply first: exact grid hits)
    i0 = pos.floor().long().clamp(max=num - 2)
    w = (pos - i0).to(x.dtype).reshape(-1, *([1] * (x.ndim - 1)))
    return x[i0] * (1.0 - w) + x[i0 + 1] * w
