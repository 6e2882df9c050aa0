"""The VAE's internal view of a motion: a root trajectory plus a pose in the body's own frame.

The 262-d feature (:mod:`umf.representation`) holds *global* joint positions: in a scene
frame people stand metres apart and face anywhere, so a raised hand is a 40 cm change in
numbers that otherwise vary by metres and turn with the person. A per-dimension
normaliser then makes the pose a small residual next to placement, and a VAE that learns
the placement well scores better than the mean pose while never learning the pose (the
bundled model's failure, measured in ``results/vae-recipe``).

The body frame splits the same numbers into what moves the person and what the body
does, without losing anything (a bijection, exact up to float rounding):

===========  ==============================================================
[0:2]        root: pelvis x, z (global, metres)
[2:4]        heading: sin(yaw), cos(yaw) of the facing direction (global)
[4:70]       joint positions relative to the pelvis's floor point, turned into the
             body's heading frame (22 x 3; the pelvis keeps only its height)
[70:136]     joint velocities turned into the heading frame (22 x 3)
[136:262]    local 6-D rotations of joints 1..21 (unchanged)
[262:266]    foot contacts (unchanged)
===========  ==============================================================

The pose slots are invariant to where a person stands and which way they face, so their
statistics are the same in every scene and their loss weighs the pose itself; the four
trajectory numbers carry the placement. ``from_body_frame`` recomposes the global
feature exactly, so everything outside the VAE still sees the 262-d layout.
"""

from __future__ import annotations

import math

import torch

from umf.representation import CONTACT, FEATURE_DIM, POS, ROT, VEL, Normalizer, heading_angle
from umf.skeleton import NUM_JOINTS

Tensor = torch.Tensor

BODY_DIM = FEATURE_DIM + 4
ROOT = slice(0, 2)
HEADING = slice(2, 4)
TRAJECTORY = slice(0, 4)
LOCAL_POS = slice(4, 70)
LOCAL_VEL = slice(70, 136)
BODY_ROT = slice(136, 262)
BODY_CONTACT = slice(262, 266)
BODY_GROUPS = {
    "trajectory": TRAJECTORY,
    "positions": LOCAL_POS,
    "velocities": LOCAL_VEL,
    "rotations": BODY_ROT,
    "contacts": BODY_CONTACT,
}


def _turn(v: Tensor, sin: Tensor, cos: Tensor) -> Tensor:
    """Rotate vectors (..., J, 3) about +Y by the yaw whose sin/cos are (...,) each.

    Same convention as :func:`umf.rotations.yaw_matrix`: +Z turns to (sin, 0, cos).
    """
    s, c = sin[..., None], cos[..., None]
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return torch.stack([c * x + s * z, y, -s * x + c * z], dim=-1)


def to_body_frame(features: Tensor) -> Tensor:
    """Global features (..., T, 262) -> body-frame features (..., T, 266)."""
    lead = features.shape[:-1]
    pos = features[..., POS].reshape(*lead, NUM_JOINTS, 3)
    vel = features[..., VEL].reshape(*lead, NUM_JOINTS, 3)
    yaw = heading_angle(pos)
    sin, cos = torch.sin(yaw), torch.cos(yaw)
    root = pos[..., 0, :].clone()
    root[..., 1] = 0.0
    local_pos = _turn(pos - root[..., None, :], -sin, cos)  # turning by -yaw
    local_vel = _turn(vel, -sin, cos)
    return torch.cat(
        [
            root[..., [0, 2]],
            torch.stack([sin, cos], dim=-1),
            local_pos.reshape(*lead, 66),
            local_vel.reshape(*lead, 66),
            features[..., ROT],
            features[..., CONTACT],
        ],
        dim=-1,
    )


def from_body_frame(body: Tensor) -> Tensor:
    """Body-frame features (..., T, 266) -> global features (..., T, 262).

    The heading pair is projected onto the unit circle first, so a decoder's
    (sin, cos) of any length still gives a rotation.
    """
    lead = body.shape[:-1]
    heading = body[..., HEADING]
    heading = heading / heading.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    sin, cos = heading[..., 0], heading[..., 1]
    zero = torch.zeros_like(body[..., 0])
    root = torch.stack([body[..., 0], zero, body[..., 1]], dim=-1)
    pos = _turn(body[..., LOCAL_POS].reshape(*lead, NUM_JOINTS, 3), sin, cos) + root[..., None, :]
    vel = _turn(body[..., LOCAL_VEL].reshape(*lead, NUM_JOINTS, 3), sin, cos)
    return torch.cat(
        [pos.reshape(*lead, 66), vel.reshape(*lead, 66), body[..., BODY_ROT],
         body[..., BODY_CONTACT]],
        dim=-1,
    )  # fmt: skip


def fit_body_normalizer(
    features: Tensor, placement_radius: float = 0.0, min_std: float = 1e-2
) -> Normalizer:
    """Per-dimension statistics of body-frame features, from global frames (N, 262).

    The pose slots do not depend on placement, so canonical corpus frames give their
    statistics exactly. The trajectory slots do: when training places people at a random
    yaw and within ``placement_radius`` metres (uniform per axis), root x/z have mean 0
    and variance (canonical spread)/2 + radius^2/3, and sin/cos of a uniform yaw have
    mean 0 and variance 1/2. Contacts stay unscaled (0/1 labels).
    """
    body = to_body_frame(features.reshape(-1, features.shape[-1]).double())
    mean, std = body.mean(0), body.std(0).clamp_min(min_std)
    mean[BODY_CONTACT], std[BODY_CONTACT] = 0.0, 1.0
    if placement_radius > 0:
        spread = body[:, ROOT].pow(2).sum(-1).mean() / 2
        mean[TRAJECTORY] = 0.0
        std[ROOT] = torch.sqrt(spread + placement_radius**2 / 3)
        std[HEADING] = math.sqrt(0.5)
    return Normalizer(mean.float(), std.float())
