"""The linear (rectified) probability path shared by P-Flow and S-Flow.

Convention (SPEC section 5): t = 0 is the source (noise or context), t = 1 is data,
x_t = t * x1 + (1 - t) * x0, and the regression target is the constant velocity
x1 - x0 of that straight line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

Tensor = torch.Tensor
TimeDistribution = Literal["uniform", "logit_normal"]


@dataclass(frozen=True)
class PathSample:
    """One draw from the path: the state, its time (B,) and the velocity to regress."""

    x_t: Tensor
    t: Tensor
    target: Tensor


def expand_time(t: Tensor | float, like: Tensor) -> Tensor:
    """Broadcast a per-sample time (B,) (or a scalar) against a (B, ...) tensor."""
    t = torch.as_tensor(t, dtype=like.dtype, device=like.device)
    if t.dim() == 0:
        return t
    return t.reshape(t.shape + (1,) * (like.dim() - t.dim()))


def interpolate(x0: Tensor, x1: Tensor, t: Tensor | float) -> Tensor:
    """x_t = t * x1 + (1 - t) * x0."""
    tt = expand_time(t, x1)
    return tt * x1 + (1 - tt) * x0


def target_velocity(x0: Tensor, x1: Tensor) -> Tensor:
    """d x_t / dt of the linear path: x1 - x0 (independent of t)."""
    return x1 - x0


def linear_path_sample(x0: Tensor, x1: Tensor, t: Tensor) -> PathSample:
    """The state on the straight line from x0 to x1 at time t and its target velocity."""
    return PathSample(x_t=interpolate(x0, x1, t), t=t, target=target_velocity(x0, x1))


def sample_time(
    batch: int,
    *,
    distribution: TimeDistribution = "uniform",
    loc: float = 0.0,
    scale: float = 1.0,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Training times (B,) in [0, 1].

    ``logit_normal`` (t = sigmoid(loc + scale * N(0, 1))) concentrates training on the
    middle of the path, where the velocity is hardest to predict (SD3-style).
    """
    if distribution == "uniform":
        return torch.rand(batch, generator=generator, device=device, dtype=dtype)
    if distribution == "logit_normal":
        z = torch.randn(batch, generator=generator, device=device, dtype=dtype)
        return torch.sigmoid(loc + scale * z)
    raise ValueError(f"unknown time distribution {distribution!r}")


def flow_matching_loss(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean squared error; with ``mask`` only the valid entries count.

    ``mask`` (e.g. (B, p) valid tokens) is broadcast over trailing dims. Each sample is
    averaged over its own valid entries first, then samples are averaged, so a sample at
    a coarse pyramid stage (fewer valid tokens) weighs as much as a full-resolution one.
    """
    sq = (pred - target).square()
    if mask is None:
        return sq.mean()
    m = mask.to(sq.dtype)
    m = m.reshape(m.shape + (1,) * (sq.dim() - m.dim())).expand_as(sq)
    dims = tuple(range(1, sq.dim()))
    per_sample = (sq * m).sum(dims) / m.sum(dims).clamp_min(1.0)
    return per_sample.mean()
