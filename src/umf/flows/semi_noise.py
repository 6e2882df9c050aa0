"""S-Flow: the semi-noise joint path for reactions (paper Sec. 4.2.2, SPEC 7).

The state is the channel concatenation of two straight paths at the same t:

    [ t*C + (1-t)*eps  ||  t*W + (1-t)*C ]      target  [ C - eps || W - C ]

The first half reconstructs the context C from noise (a regulariser that forces the
network to model the context globally); the second half transforms the context into
the reaction W. Sampling starts at [eps || C] and reads the reaction from the second
half at t = 1. ``reaction_only`` is the noise-free ablation (state t*W + (1-t)*C).

``reaction_noise`` sigma > 0 (not in the paper) starts the reaction half at C + sigma*eps'
(eps' independent of eps) instead of C itself, in training and sampling alike: with the
authors' path person 2's variation has to pass from the context half's noise, and a
network that does not carry it over returns the conditional mean of W (for a gait, a still
pose; ``results/flows-long-h200-20261126``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch

from umf.flows.noise import Generators, randn
from umf.flows.paths import (
    TimeDistribution,
    flow_matching_loss,
    interpolate,
    sample_time,
    target_velocity,
)
from umf.flows.solvers import Method, ODESolution, Velocity, integrate, remaining_steps

Tensor = torch.Tensor


@dataclass(frozen=True)
class SemiNoiseSample:
    """Network input x (B, p, 2r) (or (B, p, r) reaction-only), time t (B,), target."""

    x: Tensor
    t: Tensor
    target: Tensor


class SemiNoiseLoss(NamedTuple):
    """total = reaction + lambda_recon * recon (recon is 0 for the reaction-only path)."""

    total: Tensor
    reaction: Tensor
    recon: Tensor


def split_halves(x: Tensor) -> tuple[Tensor, Tensor]:
    """(context half, reaction half) of a joint (..., 2r) tensor."""
    r2 = x.shape[-1]
    if r2 % 2:
        raise ValueError(f"joint state needs an even channel count, got {r2}")
    return x[..., : r2 // 2], x[..., r2 // 2 :]


def semi_noise_state(
    context: Tensor,
    reaction: Tensor,
    eps: Tensor,
    t: Tensor,
    *,
    reaction_only: bool = False,
    reaction_start: Tensor | None = None,
) -> SemiNoiseSample:
    """The joint state and target at time t (B,) for given C, W and eps; the reaction half
    runs from ``reaction_start`` (default C) to W."""
    start = context if reaction_start is None else reaction_start
    react_x = interpolate(start, reaction, t)
    react_v = target_velocity(start, reaction)
    if reaction_only:
        return SemiNoiseSample(x=react_x, t=t, target=react_v)
    ctx_x = interpolate(eps, context, t)
    ctx_v = target_velocity(eps, context)
    return SemiNoiseSample(
        x=torch.cat([ctx_x, react_x], dim=-1),
        t=t,
        target=torch.cat([ctx_v, react_v], dim=-1),
    )


def semi_noise_training_sample(
    context: Tensor,
    reaction: Tensor,
    *,
    reaction_only: bool = False,
    generator: torch.Generator | None = None,
    time_distribution: TimeDistribution = "uniform",
    time_loc: float = 0.0,
    time_scale: float = 1.0,
    reaction_noise: float = 0.0,
) -> SemiNoiseSample:
    """Draw t and eps (and eps' for ``reaction_noise``) and build the training state (SPEC 7)."""
    if context.shape != reaction.shape:
        raise ValueError(f"context {tuple(context.shape)} vs reaction {tuple(reaction.shape)}")
    t = sample_time(
        context.shape[0],
        distribution=time_distribution,
        loc=time_loc,
        scale=time_scale,
        generator=generator,
        device=context.device,
        dtype=context.dtype,
    )
    eps = torch.randn(
        context.shape, generator=generator, device=context.device, dtype=context.dtype
    )
    start = None
    if reaction_noise:
        start = context + reaction_noise * torch.randn(
            context.shape, generator=generator, device=context.device, dtype=context.dtype
        )
    return semi_noise_state(context, reaction, eps, t, reaction_only=reaction_only,
                            reaction_start=start)  # fmt: skip


def reaction_endpoint(x: Tensor, pred: Tensor, t: Tensor, *, reaction_only: bool = False) -> Tensor:
    """The reaction the predicted velocity points at, x_t + (1 - t) v, from the joint state
    x and prediction pred (B, p, 2r) (or (B, p, r) reaction-only) at t (B,): the straight
    path's end, exact when pred is the target velocity (what a loss on the decoded
    reaction reads)."""
    if not reaction_only:
        x, pred = split_halves(x)[1], split_halves(pred)[1]
    return x + (1.0 - t.to(x.dtype))[:, None, None] * pred


def semi_noise_loss(
    pred: Tensor,
    target: Tensor,
    *,
    lambda_recon: float = 1.0,
    reaction_only: bool = False,
    mask: Tensor | None = None,
) -> SemiNoiseLoss:
    """MSE on the reaction half + lambda_recon * MSE on the context half.

    ``lambda_recon = 0`` is the 'no reconstruction loss' ablation (the context half is
    still part of the state, only its supervision is dropped).
    """
    if reaction_only:
        react = flow_matching_loss(pred, target, mask)
        return SemiNoiseLoss(total=react, reaction=react, recon=torch.zeros_like(react))
    p_ctx, p_react = split_halves(pred)
    t_ctx, t_react = split_halves(target)
    react = flow_matching_loss(p_react, t_react, mask)
    recon = flow_matching_loss(p_ctx, t_ctx, mask)
    return SemiNoiseLoss(total=react + lambda_recon * recon, reaction=react, recon=recon)


def semi_noise_initial_state(
    context: Tensor,
    *,
    reaction_only: bool = False,
    noise: Tensor | None = None,
    generator: Generators = None,
    reaction_noise: float = 0.0,
) -> Tensor:
    """The t = 0 state [eps || C] (or C alone for the reaction-only path); with
    ``reaction_noise`` the reaction half is C + sigma*eps', drawn after eps."""
    start = context
    if not reaction_only and noise is None:
        noise = randn(context.shape, generator, device=context.device, dtype=context.dtype)
    if reaction_noise:
        start = context + reaction_noise * randn(
            context.shape, generator, device=context.device, dtype=context.dtype
        )
    if reaction_only:
        return start
    return torch.cat([noise, start], dim=-1)


def warm_state(
    x0: Tensor, context: Tensor, warm: Tensor, t: float, *, reaction_only: bool = False
) -> Tensor:
    """The joint state at time ``t`` on the path from ``x0`` ([eps || start]) to [C || warm]:
    t*C + (1-t)*eps in the context half, t*warm + (1-t)*start in the reaction half.

    Why: from the near-deterministic start the first Euler steps point at the average
    reaction, a body that glides (``research/glide_states.py``); on the training path
    towards one particular reaction the predictions stride.
    """
    if not 0.0 < t < 1.0:
        raise ValueError(f"a warm start needs 0 < t < 1, got {t}")
    end = warm if reaction_only else torch.cat([context, warm], dim=-1)
    return interpolate(x0, end, t)


def sample_semi_noise(
    velocity: Velocity,
    context: Tensor,
    *,
    steps: int = 10,
    method: Method = "euler",
    reaction_only: bool = False,
    noise: Tensor | None = None,
    generator: Generators = None,
    cond: Mapping[str, Any] | None = None,
    reaction_noise: float = 0.0,
    warm: Tensor | None = None,
    warm_t: float = 0.0,
) -> ODESolution:
    """Integrate the joint state from t = 0 to 1 once and return the reaction half.

    One pass yields the reaction (the authors' release ran the ODE twice; SPEC 7 (b)).
    ``warm`` (B, p, r), a proposed reaction: start at ``warm_t`` on the straight path from
    the t = 0 state towards [C || warm] (the state training puts there had the reaction
    been ``warm``) with the remaining share of ``steps`` (:func:`warm_state`).
    """
    x0 = semi_noise_initial_state(
        context, reaction_only=reaction_only, noise=noise, generator=generator,
        reaction_noise=reaction_noise,
    )  # fmt: skip
    t0 = 0.0
    if warm is not None and warm_t > 0:
        x0, t0 = warm_state(x0, context, warm, warm_t, reaction_only=reaction_only), warm_t
        steps = remaining_steps(steps, t0)
    x1, nfe = integrate(velocity, x0, steps=steps, t0=t0, method=method, cond=cond)
    reaction = x1 if reaction_only else split_halves(x1)[1]
    return ODESolution(reaction, nfe)
