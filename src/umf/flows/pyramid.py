"""P-Flow: pyramidal flow matching over the latent tokens (paper Sec. 4.2.1, SPEC 6).

Stage k (1 = full resolution, K = coarsest) lives on Down^(k-1) of the (B, p, r) latent
and covers the time window [s_k, e_k] (s_K = 0, e_1 = 1). Two token layouts:

* ``"1d"``: the token axis; Down averages consecutive pairs (block b = 2), Up repeats.
* ``"2d"``: the p tokens as a sqrt(p) x sqrt(p) grid (row-major); Down is 2x2 average
  pooling (b = 4), Up is nearest. This is what the authors' release does.

Jump between stages (derivation, checked by Monte Carlo in tests/test_flow_pyramid.py).
Given z1, the coarse end point is e*D + (1-e)*eps_c with eps_c ~ N(0, I) at the coarse
resolution (fresh unit-variance noise: Down is never applied to noise). Nearest Up makes
that noise fully correlated inside each block of b fine tokens: per channel and block it
has covariance J (all ones). The jump z_s = (s/e) * Up(z_e) + alpha * n', with n' ~
N(0, Sigma'), Sigma' = (1+g) I - g J per block, must reproduce the finer stage's start
s * Up(D) + (1-s) * eps_f, i.e. mean s * Up(D) (true for the s/e factor) and covariance
(1-s)^2 I. Equating the I and J parts:

    alpha^2 (1 + g) = (1 - s)^2                      ->  alpha = (1 - s) / sqrt(1 + g)
    (s/e)^2 (1 - e)^2 = alpha^2 g                    ->  s(1-e)/e = (1-s) sqrt(g/(1+g))

Sigma' is PSD iff 0 <= g <= 1/(b-1) (its eigenvalues are 1+g and 1-(b-1)g). The
constants depend on g only; b only bounds g. g = 1/(b-1) (the default) makes the block
mean of n' exactly zero: the coarse state alone supplies the block averages and fresh
noise only fills the within-block detail, which gives the smallest e_k for a given
s_{k-1} (the least re-noising). b = 4, g = 1/3 gives the paper's alpha = sqrt(3)(1-s)/2
and e = 2s/(1+s); b = 2, g = 1 gives alpha = (1-s)/sqrt(2), e = sqrt(2)s/(1+(sqrt(2)-1)s).

Time: the training target end - start is d x / d t' with the local time
t' = (t - s_k) / (e_k - s_k), so the sampler integrates t' from 0 to 1 in each stage and
shows the model the global t plus the stage index (windows overlap, e_k > s_{k-1}, so t
alone would be ambiguous).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch

from umf.flows.noise import Generators, randn
from umf.flows.paths import TimeDistribution, interpolate, sample_time
from umf.flows.solvers import Method, ODESolution, Velocity, integrate, remaining_steps

Tensor = torch.Tensor
Layout = Literal["1d", "2d"]

_G_TOL = 1e-9


# ------------------------------------------------------------------ resampling
def _grid_side(n: int) -> int:
    side = math.isqrt(n)
    if side * side != n or side % 2:
        raise ValueError(f"2-D layout needs an even square token count, got {n}")
    return side


def down_1d(x: Tensor, levels: int = 1) -> Tensor:
    """Average consecutive token pairs ``levels`` times: (..., n, r) -> (..., n/2^l, r)."""
    for _ in range(levels):
        n = x.shape[-2]
        if n % 2:
            raise ValueError(f"cannot halve {n} tokens")
        x = x.unflatten(-2, (n // 2, 2)).mean(-2)
    return x


def up_1d(x: Tensor, levels: int = 1) -> Tensor:
    """Nearest upsampling of the token axis: repeat each token 2^levels times."""
    return x.repeat_interleave(2**levels, dim=-2) if levels else x


def down_2d(x: Tensor, levels: int = 1) -> Tensor:
    """2x2 average pooling of the row-major token grid: (..., h*w, r) -> (..., h*w/4, r)."""
    for _ in range(levels):
        *lead, n, r = x.shape
        h = _grid_side(n)
        x = x.reshape(*lead, h // 2, 2, h // 2, 2, r).mean(dim=(-4, -2))
        x = x.reshape(*lead, n // 4, r)
    return x


def up_2d(x: Tensor, levels: int = 1) -> Tensor:
    """Nearest 2x upsampling of the row-major token grid, ``levels`` times."""
    for _ in range(levels):
        *lead, n, r = x.shape
        h = math.isqrt(n)
        if h * h != n:
            raise ValueError(f"2-D layout needs a square token count, got {n}")
        x = x.reshape(*lead, h, 1, h, 1, r).expand(*lead, h, 2, h, 2, r)
        x = x.reshape(*lead, 4 * n, r)
    return x


def down(x: Tensor, layout: Layout, levels: int = 1) -> Tensor:
    """Down for the given layout (average over blocks of ``block_size(layout)`` tokens)."""
    return down_1d(x, levels) if layout == "1d" else down_2d(x, levels)


def up(x: Tensor, layout: Layout, levels: int = 1) -> Tensor:
    """Nearest Up for the given layout (right inverse of ``down``: down(up(x)) == x)."""
    return up_1d(x, levels) if layout == "1d" else up_2d(x, levels)


def split_detail(x: Tensor, layout: Layout) -> tuple[Tensor, Tensor]:
    """(coarse, detail) of fine-resolution tokens: each token's block mean, Up(Down(x)), and
    the token less it (the part only a finer stage adds; the blocks' means of it are 0)."""
    coarse = up(down(x, layout), layout)
    return coarse, x - coarse


def block_size(layout: Layout) -> int:
    """Fine tokens per coarse token: 2 (1-D pairs) or 4 (2x2 grid cells)."""
    if layout not in ("1d", "2d"):
        raise ValueError(f"unknown layout {layout!r}")
    return 2 if layout == "1d" else 4


# --------------------------------------------------------------- jump constants
def max_correlation(b: int) -> float:
    """Largest g keeping Sigma' = (1+g)I - gJ PSD over b elements: 1/(b-1)."""
    if b < 2:
        raise ValueError(f"block size must be >= 2, got {b}")
    return 1.0 / (b - 1)


def check_correlation(g: float, b: int) -> None:
    """Raise unless 0 <= g <= 1/(b-1), i.e. Sigma' is a covariance over blocks of b."""
    if not (0.0 <= g <= max_correlation(b) + _G_TOL):
        raise ValueError(f"g={g} outside [0, {max_correlation(b):.6g}] for block size {b}")


def jump_end(s: float, g: float) -> float:
    """e_k for a given s_{k-1}: the solution of s(1-e)/e = (1-s) sqrt(g/(1+g))."""
    if not 0.0 < s < 1.0:
        raise ValueError(f"start of the finer stage must lie in (0, 1), got {s}")
    c = math.sqrt(g / (1.0 + g))
    return s / (s + (1.0 - s) * c)


def jump_alpha(s: float, g: float) -> float:
    """Scale of the block noise at the jump: (1 - s_{k-1}) / sqrt(1 + g)."""
    return (1.0 - s) / math.sqrt(1.0 + g)


@dataclass(frozen=True)
class StageWindow:
    """Time window [start, end] of one stage; ``level`` = Down applications (stage - 1)."""

    stage: int
    start: float
    end: float

    @property
    def level(self) -> int:
        return self.stage - 1

    def global_time(self, t_local: Tensor | float) -> Tensor | float:
        """t = s_k + t' (e_k - s_k)."""
        return self.start + t_local * (self.end - self.start)


def stage_windows(
    num_stages: int, g: float, starts: Sequence[float] | None = None
) -> tuple[StageWindow, ...]:
    """Windows ordered coarse -> fine (stage K first).

    ``starts`` are s_K..s_1 (s_K must be 0); by default uniform, s_k = (K - k) / K. The
    ends follow from the jump condition, e_k = jump_end(s_{k-1}, g), and e_1 = 1.
    """
    if num_stages < 1:
        raise ValueError(f"num_stages must be >= 1, got {num_stages}")
    k = num_stages
    s = list(starts) if starts is not None else [(k - i) / k for i in range(k, 0, -1)]
    if len(s) != k or s[0] != 0.0 or any(b <= a for a, b in itertools.pairwise(s)):
        raise ValueError(f"starts must be {k} increasing values from 0, got {s}")
    ends = [jump_end(s_next, g) for s_next in s[1:]] + [1.0]
    return tuple(StageWindow(stage=k - i, start=s[i], end=ends[i]) for i in range(k))


# ------------------------------------------------------------------ block noise
def block_noise_from_white(z: Tensor, layout: Layout, g: float) -> Tensor:
    """Map i.i.d. N(0, 1) fine-resolution noise to N(0, Sigma') per block.

    Sigma' = (1+g)(I - J/b) + (1-(b-1)g) J/b, so its symmetric square root is
    sqrt(1+g) * (remove block mean) + sqrt(1-(b-1)g) * (keep block mean).
    """
    b = block_size(layout)
    check_correlation(g, b)
    m, detail = split_detail(z, layout)
    keep = math.sqrt(max(0.0, 1.0 - (b - 1) * g))
    return math.sqrt(1.0 + g) * detail + keep * m


def block_noise(
    shape: Sequence[int],
    layout: Layout,
    g: float,
    *,
    generator: Generators = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """n' ~ N(0, Sigma') at the fine resolution ``shape`` = (..., n, r)."""
    z = randn(shape, generator, device=device, dtype=dtype)
    return block_noise_from_white(z, layout, g)


def jump(
    z_end: Tensor,
    *,
    s: float,
    e: float,
    alpha: float,
    layout: Layout,
    g: float,
    generator: Generators = None,
) -> Tensor:
    """Renoising jump (Eq. 11): z_s = (s/e) Up(z_e) + alpha n', n' ~ N(0, Sigma')."""
    z_up = up(z_end, layout)
    n = block_noise(
        z_up.shape, layout, g, generator=generator, device=z_up.device, dtype=z_up.dtype
    )
    return (s / e) * z_up + alpha * n


# ---------------------------------------------------------------- configuration
@dataclass(frozen=True)
class PyramidConfig:
    """Pyramid shape: layout, K stages, tokens at full resolution, g and the starts.

    ``g`` None means 1/(b-1) (block averages carried over noise-free). num_stages = 1 is
    plain flow matching at full resolution (the 'no pyramid' ablation).
    """

    layout: Layout = "1d"
    num_stages: int = 2
    num_tokens: int = 16
    g: float | None = None
    starts: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        b = block_size(self.layout)
        if self.g is None:
            object.__setattr__(self, "g", max_correlation(b))
        check_correlation(self.correlation, b)
        if self.num_stages < 1:
            raise ValueError(f"num_stages must be >= 1, got {self.num_stages}")
        n = self.num_tokens
        if self.layout == "2d":
            side = math.isqrt(n)
            if side * side != n or side % (2 ** (self.num_stages - 1)):
                raise ValueError(f"{n} tokens cannot form a {self.num_stages}-stage grid")
        elif n % (2 ** (self.num_stages - 1)):
            raise ValueError(f"{n} tokens cannot be halved {self.num_stages - 1} times")
        stage_windows(self.num_stages, self.correlation, self.starts)  # validate

    @property
    def correlation(self) -> float:
        """g as a float (resolved default)."""
        assert self.g is not None
        return float(self.g)

    @property
    def block(self) -> int:
        return block_size(self.layout)

    @property
    def windows(self) -> tuple[StageWindow, ...]:
        """Stage windows ordered coarse -> fine."""
        return stage_windows(self.num_stages, self.correlation, self.starts)

    def window(self, stage: int) -> StageWindow:
        return self.windows[self.num_stages - stage]

    def tokens(self, stage: int) -> int:
        """Token count at ``stage`` (1 = full resolution)."""
        return self.num_tokens // self.block ** (stage - 1)


# --------------------------------------------------------------------- training
@dataclass(frozen=True)
class PyramidTrainingSample:
    """A P-Flow training batch, zero-padded to the full token count.

    ``x``/``target`` (B, p, r) hold the first ``config.tokens(stage)`` tokens of each
    sample (``mask`` (B, p) marks them); ``t`` is the global time shown to the model,
    ``t_local`` the in-window time t' the target is a derivative with respect to.
    """

    x: Tensor
    t: Tensor
    t_local: Tensor
    target: Tensor
    stage: Tensor
    mask: Tensor


def stage_endpoints(
    x_level: Tensor, eps: Tensor, window: StageWindow, layout: Layout
) -> tuple[Tensor, Tensor]:
    """Start/end of a stage (Eqs. 6-7) sharing one noise ``eps`` at its resolution.

    ``x_level`` = Down^(k-1)(z1). start = s Up(Down(x_level)) + (1-s) eps,
    end = e x_level + (1-e) eps.
    """
    s, e = window.start, window.end
    start = (1.0 - s) * eps
    if s > 0.0:
        start = start + s * up(down(x_level, layout), layout)
    end = e * x_level + (1.0 - e) * eps
    return start, end


def _stage_tensor(
    stage: int | Tensor | None,
    config: PyramidConfig,
    batch: int,
    generator: torch.Generator | None,
    device: torch.device,
) -> Tensor:
    if stage is None:
        return torch.randint(1, config.num_stages + 1, (batch,), generator=generator, device=device)
    st = torch.as_tensor(stage, dtype=torch.long, device=device).expand(batch).clone()
    if bool(((st < 1) | (st > config.num_stages)).any()):
        raise ValueError(f"stage must lie in [1, {config.num_stages}]")
    return st


def pyramid_training_sample(
    z1: Tensor,
    config: PyramidConfig,
    *,
    stage: int | Tensor | None = None,
    generator: torch.Generator | None = None,
    time_distribution: TimeDistribution = "uniform",
    time_loc: float = 0.0,
    time_scale: float = 1.0,
) -> PyramidTrainingSample:
    """Draw stages (uniform per sample unless ``stage`` is given), t' and noise (Eqs. 6-9).

    Pass an int ``stage`` to train one stage per batch and crop ``x[:, :tokens]`` to save
    compute; the padded form lets one batch mix stages (use ``mask`` in the loss).
    """
    b, p = z1.shape[0], z1.shape[-2]
    if p != config.num_tokens:
        raise ValueError(f"expected {config.num_tokens} tokens, got {p}")
    stages = _stage_tensor(stage, config, b, generator, z1.device)
    t_local = sample_time(
        b,
        distribution=time_distribution,
        loc=time_loc,
        scale=time_scale,
        generator=generator,
        device=z1.device,
        dtype=z1.dtype,
    )
    eps_full = torch.randn(z1.shape, generator=generator, device=z1.device, dtype=z1.dtype)
    x = torch.zeros_like(z1)
    target = torch.zeros_like(z1)
    mask = torch.zeros(b, p, dtype=torch.bool, device=z1.device)
    t = torch.zeros_like(t_local)
    for w in config.windows:
        idx = (stages == w.stage).nonzero().squeeze(1)
        if idx.numel() == 0:
            continue
        x_level = down(z1[idx], config.layout, w.level)
        n = x_level.shape[-2]
        start, end = stage_endpoints(x_level, eps_full[idx, :n], w, config.layout)
        x[idx, :n] = interpolate(start, end, t_local[idx])
        target[idx, :n] = end - start
        mask[idx, :n] = True
        t[idx] = w.start + t_local[idx] * (w.end - w.start)
    return PyramidTrainingSample(x=x, t=t, t_local=t_local, target=target, stage=stages, mask=mask)


# --------------------------------------------------------------------- sampling
def default_steps(num_stages: int, total: int = 50) -> tuple[int, ...]:
    """Per-stage steps coarse -> fine: the paper's 45/5 for K = 2, else an even split."""
    if num_stages == 1:
        return (total,)
    if num_stages == 2 and total == 50:
        return (45, 5)
    base, extra = divmod(total, num_stages)
    return tuple(base + (1 if i < extra else 0) for i in range(num_stages))


def initial_noise(
    config: PyramidConfig,
    batch: int,
    width: int,
    *,
    generator: Generators = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Pure noise at the coarsest stage's resolution, (B, tokens(K), r)."""
    shape = (batch, config.tokens(config.num_stages), width)
    return randn(shape, generator, device=device, dtype=dtype)


def sample_pyramid(
    velocity: Velocity,
    noise: Tensor,
    config: PyramidConfig,
    *,
    steps: Sequence[int] | None = None,
    method: Method = "euler",
    generator: Generators = None,
    cond: Mapping[str, Any] | None = None,
) -> ODESolution:
    """Generate full-resolution latents (Algorithm 1, lines 4-10).

    ``velocity(x, t, stage=..., **cond)`` gets the global time t (B,) and the stage (B,)
    long. Each stage integrates t' in [0, 1] with its own step count (``steps`` ordered
    coarse -> fine); between stages the renoising jump is applied. Returns the final
    latent and the total number of velocity evaluations.
    """
    windows = config.windows
    steps = tuple(steps) if steps is not None else default_steps(config.num_stages)
    if len(steps) != len(windows):
        raise ValueError(f"need {len(windows)} step counts (coarse -> fine), got {steps}")
    if noise.shape[-2] != config.tokens(config.num_stages):
        raise ValueError(f"initial noise must have {config.tokens(config.num_stages)} tokens")
    extra = dict(cond or {})
    x, nfe = noise, 0
    for i, (w, n_steps) in enumerate(zip(windows, steps, strict=True)):
        stage = torch.full((x.shape[0],), w.stage, dtype=torch.long, device=x.device)
        x, n = integrate(_local_field(velocity, w, stage, extra), x, steps=n_steps, method=method)
        nfe += n
        if i + 1 < len(windows):
            s_next = windows[i + 1].start
            x = jump(
                x,
                s=s_next,
                e=w.end,
                alpha=jump_alpha(s_next, config.correlation),
                layout=config.layout,
                g=config.correlation,
                generator=generator,
            )
    return ODESolution(x, nfe)


def finest_warm_state(proposal: Tensor, eps: Tensor, window: StageWindow, layout: Layout,
                      t_local: float) -> Tensor:  # fmt: skip
    """The finest stage's state at local time ``t_local`` on its training path towards
    ``proposal`` (B, p, r), full resolution: what :func:`pyramid_training_sample` puts
    there had the motion been ``proposal``, with noise ``eps`` (Eqs. 6-7, e = 1)."""
    if not 0.0 < t_local < 1.0:
        raise ValueError(f"a warm start needs 0 < t < 1, got {t_local}")
    if window.level != 0:
        raise ValueError(f"a warm start enters the finest stage, not stage {window.stage}")
    start, end = stage_endpoints(proposal, eps, window, layout)
    return interpolate(start, end, t_local)


def sample_finest_from(
    velocity: Velocity,
    proposal: Tensor,
    config: PyramidConfig,
    t_local: float,
    *,
    steps: int,
    method: Method = "euler",
    generator: Generators = None,
) -> ODESolution:
    """Full-resolution latents sampled again from ``proposal`` (B, p, r): enter the finest
    stage at ``t_local`` on the path towards it (:func:`finest_warm_state`) and integrate
    the rest of that stage with the remaining share of its ``steps`` (at least one). The
    coarser stages are skipped: the proposal already says what they would have."""
    window = config.windows[-1]
    eps = randn(proposal.shape, generator, device=proposal.device, dtype=proposal.dtype)
    x = finest_warm_state(proposal, eps, window, config.layout, t_local)
    stage = torch.full((x.shape[0],), window.stage, dtype=torch.long, device=x.device)
    n = remaining_steps(steps, t_local)
    return integrate(_local_field(velocity, window, stage, {}), x, steps=n, t0=t_local,
                     method=method)  # fmt: skip


def _local_field(
    velocity: Velocity, window: StageWindow, stage: Tensor, cond: Mapping[str, Any]
) -> Callable[..., Tensor]:
    """The field in local time t': the model sees global t and the stage index."""

    def field(x: Tensor, t_local: Tensor) -> Tensor:
        return velocity(x, window.global_time(t_local), stage=stage, **cond)

    return field
