"""Fixed-step ODE solvers for dx/dt = v(x, t), with evaluation counting.

A velocity model is any callable ``v(x, t, **cond)`` where ``t`` is a (B,) tensor of
the current time (one entry per sample, same dtype/device as x). Fixed grids keep the
number of function evaluations (NFE) known in advance, which is what the step-budget
ablations of the paper report.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping
from typing import Any, Literal, NamedTuple, Protocol

import torch

Tensor = torch.Tensor
Method = Literal["euler", "heun", "rk4"]
Field = Callable[[Tensor, float], Tensor]  # f(x, t) with a scalar time


class Velocity(Protocol):
    """v(x, t, **cond) -> dx/dt, with t of shape (B,)."""

    def __call__(self, x: Tensor, t: Tensor, **cond: Any) -> Tensor: ...


class ODESolution(NamedTuple):
    """Final state and number of velocity evaluations used to reach it."""

    x: Tensor
    nfe: int


# ----------------------------------------------------------------- single steps
def euler_step(f: Field, x: Tensor, t: float, h: float) -> tuple[Tensor, int]:
    """First order: x + h f(x, t). 1 evaluation."""
    return x + h * f(x, t), 1


def heun_step(f: Field, x: Tensor, t: float, h: float) -> tuple[Tensor, int]:
    """Second order (explicit trapezoid). 2 evaluations."""
    k1 = f(x, t)
    k2 = f(x + h * k1, t + h)
    return x + 0.5 * h * (k1 + k2), 2


def rk4_step(f: Field, x: Tensor, t: float, h: float) -> tuple[Tensor, int]:
    """Classical fourth-order Runge-Kutta. 4 evaluations."""
    k1 = f(x, t)
    k2 = f(x + 0.5 * h * k1, t + 0.5 * h)
    k3 = f(x + 0.5 * h * k2, t + 0.5 * h)
    k4 = f(x + h * k3, t + h)
    return x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4), 4


_STEPPERS: Mapping[str, Callable[[Field, Tensor, float, float], tuple[Tensor, int]]] = {
    "euler": euler_step,
    "heun": heun_step,
    "rk4": rk4_step,
}

EVALS_PER_STEP: Mapping[str, int] = {"euler": 1, "heun": 2, "rk4": 4}


def time_grid(steps: int, t0: float = 0.0, t1: float = 1.0) -> list[float]:
    """``steps + 1`` uniformly spaced times from t0 to t1 (both included)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    return [t0 + (t1 - t0) * i / steps for i in range(steps + 1)]


def batch_time(t: float, x: Tensor) -> Tensor:
    """The scalar time as a (B,) tensor matching x, the form velocity models receive."""
    return torch.full((x.shape[0],), float(t), dtype=x.dtype, device=x.device)


def remaining_steps(steps: int, t0: float) -> int:
    """Steps left of a ``steps``-step schedule for a path entered at ``t0``: the warm starts
    (P-Flow's finest stage, S-Flow's second pass) take the same step size as a full pass."""
    return max(1, round(steps * (1.0 - t0)))


def integrate(
    velocity: Velocity,
    x0: Tensor,
    *,
    steps: int | None = None,
    t0: float = 0.0,
    t1: float = 1.0,
    grid: list[float] | None = None,
    method: Method = "euler",
    cond: Mapping[str, Any] | None = None,
) -> ODESolution:
    """Integrate dx/dt = velocity(x, t, **cond) along ``grid`` (or ``steps`` uniform steps).

    Returns the state at the last grid time and the number of velocity evaluations.
    """
    if method not in _STEPPERS:
        raise ValueError(f"unknown method {method!r}; choose from {sorted(_STEPPERS)}")
    if grid is None:
        if steps is None:
            raise ValueError("give either steps or grid")
        grid = time_grid(steps, t0, t1)
    kwargs = dict(cond or {})

    def f(x: Tensor, t: float) -> Tensor:
        return velocity(x, batch_time(t, x), **kwargs)

    stepper = _STEPPERS[method]
    x, nfe = x0, 0
    for ta, tb in itertools.pairwise(grid):
        x, n = stepper(f, x, ta, tb - ta)
        nfe += n
    return ODESolution(x, nfe)


# --------------------------------------------------------- classifier-free guidance
def guidance_combine(v_cond: Tensor, v_uncond: Tensor, scale: float) -> Tensor:
    """v_uncond + scale * (v_cond - v_uncond); scale 1 is the plain conditional model."""
    return v_uncond + scale * (v_cond - v_uncond)


def _stack_pair(a: Any, b: Any, key: str) -> Any:
    """Concatenate a cond/uncond pair along the batch axis (non-tensors must agree)."""
    if isinstance(a, Tensor) and isinstance(b, Tensor):
        return torch.cat([a, b], dim=0)
    if a is b or a == b:
        return a
    raise ValueError(f"cond/uncond entry {key!r} differs but is not a tensor; cannot batch")


def _repeat(value: Any, batch: int, times: int = 2) -> Any:
    """Repeat a per-sample tensor for a batch guidance stacks ``times`` times over; leave
    anything else alone."""
    if isinstance(value, Tensor) and value.dim() > 0 and value.shape[0] == batch:
        return torch.cat([value] * times, dim=0)
    return value


def classifier_free_guidance(
    velocity: Velocity,
    scale: float,
    cond: Mapping[str, Any],
    uncond: Mapping[str, Any],
    *,
    batched: bool = True,
) -> Velocity:
    """Wrap a conditional model into the guided field v_u + scale * (v_c - v_u).

    ``batched`` runs one forward over the doubled batch [cond; uncond] (tensor entries
    concatenated along dim 0), which is faster on accelerators; otherwise two calls.
    Solvers count one evaluation of the guided field per call either way: a guided
    evaluation costs one double-batch forward (batched) or two forwards (not batched).
    Extra keyword arguments given at call time (e.g. the pyramid ``stage``) go to both.
    """
    if set(cond) != set(uncond):
        raise ValueError("cond and uncond must have the same keys")

    def guided(x: Tensor, t: Tensor, **shared: Any) -> Tensor:
        if not batched:
            v_c = velocity(x, t, **shared, **cond)
            v_u = velocity(x, t, **shared, **uncond)
            return guidance_combine(v_c, v_u, scale)
        b = x.shape[0]
        both = {k: _stack_pair(cond[k], uncond[k], k) for k in cond}
        dup = {k: _repeat(v, b) for k, v in shared.items()}
        out = velocity(torch.cat([x, x], 0), torch.cat([t, t], 0), **dup, **both)
        v_c, v_u = out[:b], out[b:]
        return guidance_combine(v_c, v_u, scale)

    return guided


def composed_guidance(
    velocity: Velocity,
    scale: float,
    own_scale: float,
    both: Mapping[str, Any],
    scene: Mapping[str, Any],
    uncond: Mapping[str, Any],
    conjoin: bool = False,
) -> Velocity:
    """Guidance over two prompts, each with its own scale (compositional CFG):
    v_u + scale * (v_scene - v_u) + own_scale * (v_both - v_scene), where ``scene`` is the
    scene prompt alone and ``both`` adds each person's own prompt. One forward over the
    tripled batch [both; scene; uncond]; with ``own_scale == scale`` (and not ``conjoin``)
    it is plain CFG of ``both`` against ``uncond``, so the own prompt's pull is set apart
    from the scene's.

    ``conjoin``: ``both`` is the own prompt alone, as a prompt in its own right, and the two
    are conjoined (the AND of composable diffusion, Liu et al. 2022):
    v_u + scale * (v_scene - v_u) + own_scale * (v_own - v_u). Each prompt then pulls from
    nothing rather than the own prompt from the scene's, so a scene prompt that already says
    much ("stand facing each other") no longer mutes a gesture its network reads well alone."""
    if not set(both) == set(scene) == set(uncond):
        raise ValueError("both, scene and uncond must have the same keys")

    def guided(x: Tensor, t: Tensor, **shared: Any) -> Tensor:
        b = x.shape[0]
        three = {k: _stack_pair(_stack_pair(both[k], scene[k], k), uncond[k], k) for k in both}
        dup = {k: _repeat(v, b, 3) for k, v in shared.items()}
        out = velocity(torch.cat([x, x, x], 0), torch.cat([t, t, t], 0), **dup, **three)
        v_both, v_scene, v_u = out[:b], out[b : 2 * b], out[2 * b :]
        return v_u + scale * (v_scene - v_u) + own_scale * (v_both - (v_u if conjoin else v_scene))

    return guided
