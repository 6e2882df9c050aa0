"""Batched rotation utilities (torch, any leading shape, no per-frame loops).

Conventions used everywhere in umf:
- quaternions are (w, x, y, z), unit norm;
- rotation matrices act on column vectors: ``v' = R @ v``;
- the 6-D representation (Zhou et al. 2019) is the first two *columns* of R,
  concatenated as ``[R[:, 0], R[:, 1]]`` (the HumanML3D / InterHuman layout);
- Euler angles are in degrees, intrinsic, in the order given (the BVH convention):
  order "ZXY" means ``R = Rz @ Rx @ Ry``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

Tensor = torch.Tensor

_EPS = 1e-8


# --------------------------------------------------------------------- quaternions
def quat_identity(shape: tuple[int, ...] = (), dtype=torch.float32, device=None) -> Tensor:
    q = torch.zeros(*shape, 4, dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def quat_normalize(q: Tensor) -> Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def quat_conjugate(q: Tensor) -> Tensor:
    return torch.cat([q[..., :1], -q[..., 1:]], dim=-1)


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b`` (apply b first, then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * torch.cross(u, v, dim=-1)
    return v + w * t + torch.cross(u, t, dim=-1)


def quat_to_matrix(q: Tensor) -> Tensor:
    q = quat_normalize(q)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(m: Tensor) -> Tensor:
    """Numerically stable conversion (branch on the largest diagonal term), w >= 0."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # Four candidate solutions; pick the best conditioned one per element.
    q_abs = torch.sqrt(
        torch.stack(
            [
                1.0 + m00 + m11 + m22,
                1.0 + m00 - m11 - m22,
                1.0 - m00 + m11 - m22,
                1.0 - m00 - m11 + m22,
            ],
            dim=-1,
        ).clamp_min(0.0)
    )
    cands = torch.stack(
        [
            torch.stack([q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01], dim=-1),
            torch.stack([m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20], dim=-1),
            torch.stack([m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21], dim=-1),
            torch.stack([m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2], dim=-1),
        ],
        dim=-2,
    )
    cands = cands / (2.0 * q_abs[..., None].clamp_min(0.1))
    best = q_abs.argmax(dim=-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = quat_normalize(q)
    return torch.where(q[..., :1] < 0, -q, q)


def axis_angle_to_quat(aa: Tensor) -> Tensor:
    angle = aa.norm(dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(x/2)/x with its limit 1/2 at 0
    k = torch.where(angle < 1e-6, 0.5 - angle**2 / 48.0, torch.sin(half) / angle.clamp_min(1e-12))
    return torch.cat([torch.cos(half), aa * k], dim=-1)


def quat_to_axis_angle(q: Tensor) -> Tensor:
    q = quat_normalize(q)
    q = torch.where(q[..., :1] < 0, -q, q)
    s = q[..., 1:].norm(dim=-1, keepdim=True)
    angle = 2.0 * torch.atan2(s, q[..., :1])
    k = torch.where(s < 1e-6, 2.0 + angle**2 / 12.0, angle / s.clamp_min(1e-12))
    return q[..., 1:] * k


def axis_angle_to_matrix(aa: Tensor) -> Tensor:
    return quat_to_matrix(axis_angle_to_quat(aa))


def matrix_to_axis_angle(m: Tensor) -> Tensor:
    return quat_to_axis_angle(matrix_to_quat(m))


def quat_between(u: Tensor, v: Tensor) -> Tensor:
    """Shortest-arc rotation taking direction ``u`` to direction ``v`` (..., 3).

    Antiparallel inputs get a 180-degree turn about an axis orthogonal to ``u``.
    """
    u = F.normalize(u, dim=-1, eps=_EPS)
    v = F.normalize(v, dim=-1, eps=_EPS)
    dot = (u * v).sum(-1, keepdim=True)
    axis = torch.cross(u, v, dim=-1)
    q = torch.cat([1.0 + dot, axis], dim=-1)
    # antiparallel: pick any axis orthogonal to u
    ex = torch.zeros_like(u)
    ex[..., 0] = 1.0
    ey = torch.zeros_like(u)
    ey[..., 1] = 1.0
    ortho = torch.cross(u, torch.where(u[..., :1].abs() < 0.9, ex, ey), dim=-1)
    flip = torch.cat([torch.zeros_like(dot), F.normalize(ortho, dim=-1, eps=_EPS)], dim=-1)
    q = torch.where(dot < -1.0 + 1e-7, flip, q)
    return quat_normalize(q)


# --------------------------------------------------------------------- 6-D
def matrix_to_6d(m: Tensor) -> Tensor:
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def sixd_to_matrix(d6: Tensor) -> Tensor:
    """Gram-Schmidt back to a proper rotation (columns a, b, a x b)."""
    a = F.normalize(d6[..., 0:3], dim=-1, eps=_EPS)
    b = d6[..., 3:6]
    b = F.normalize(b - (a * b).sum(-1, keepdim=True) * a, dim=-1, eps=_EPS)
    c = torch.cross(a, b, dim=-1)
    return torch.stack([a, b, c], dim=-1)


# --------------------------------------------------------------------- Euler
def _axis_matrix(axis: str, angle_rad: Tensor) -> Tensor:
    c, s = torch.cos(angle_rad), torch.sin(angle_rad)
    o, z = torch.ones_like(c), torch.zeros_like(c)
    if axis == "X":
        rows = [o, z, z, z, c, -s, z, s, c]
    elif axis == "Y":
        rows = [c, z, s, z, o, z, -s, z, c]
    elif axis == "Z":
        rows = [c, -s, z, s, c, z, z, z, o]
    else:
        raise ValueError(f"unknown rotation axis {axis!r}")
    return torch.stack(rows, dim=-1).reshape(*angle_rad.shape, 3, 3)


def euler_to_matrix(angles_deg: Tensor, order: str) -> Tensor:
    """Intrinsic Euler angles (degrees, ``angles[..., i]`` about ``order[i]``) to matrices."""
    order = order.upper()
    if len(order) != 3 or set(order) != set("XYZ"):
        raise ValueError(f"invalid Euler order {order!r} (need a permutation of XYZ)")
    rad = torch.deg2rad(angles_deg)
    m = _axis_matrix(order[0], rad[..., 0])
    for i in (1, 2):
        m = m @ _axis_matrix(order[i], rad[..., i])
    return m


def matrix_to_euler(m: Tensor, order: str) -> Tensor:
    """Inverse of :func:`euler_to_matrix` (degrees), valid for all six Tait-Bryan orders."""
    order = order.upper()
    idx = {"X": 0, "Y": 1, "Z": 2}
    i, j, k = (idx[a] for a in order)
    if len({i, j, k}) != 3:
        raise ValueError(f"only Tait-Bryan orders are supported, got {order!r}")
    # parity of the permutation decides the sign pattern
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    # R = R_i(a) R_j(b) R_k(c): R[i, k] = sign * sin(b)
    sb = (sign * m[..., i, k]).clamp(-1.0, 1.0)
    cb = torch.hypot(m[..., i, i], m[..., i, j])  # |cos(b)|, accurate near +-90 degrees
    b = torch.atan2(sb, cb)
    a = torch.atan2(-sign * m[..., j, k], m[..., k, k])
    c = torch.atan2(-sign * m[..., i, j], m[..., i, i])
    # gimbal lock: cos(b) ~ 0, a and c share one axis; put everything into a
    lock = cb < (1e-6 if m.dtype == torch.float32 else 1e-12)
    a_lock = torch.atan2(sign * m[..., k, j], m[..., j, j])
    a = torch.where(lock, a_lock, a)
    c = torch.where(lock, torch.zeros_like(c), c)
    return torch.rad2deg(torch.stack([a, b, c], dim=-1))


def yaw_matrix(angle_rad: Tensor) -> Tensor:
    """Rotation about +Y (up)."""
    return _axis_matrix("Y", angle_rad)
