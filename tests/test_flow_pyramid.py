"""P-Flow pyramid: resampling, windows, training sample, block noise, jump, sampler.

The core check is Monte Carlo: given a fixed z1, the state right after the renoising
jump must have the mean and covariance of the finer stage's training start point, and
wrong constants must be caught by the same statistic.
"""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import pytest
import torch

from umf.flows import (
    Layout,
    PyramidConfig,
    block_noise_from_white,
    default_steps,
    down,
    flow_matching_loss,
    initial_noise,
    jump,
    jump_alpha,
    jump_end,
    pyramid_training_sample,
    sample_pyramid,
    stage_endpoints,
    stage_windows,
    up,
)
from umf.flows import pyramid as pyr
from umf.flows.pyramid import (
    StageWindow,
    block_noise,
    block_size,
    check_correlation,
    down_1d,
    down_2d,
    max_correlation,
    up_1d,
    up_2d,
)

F64 = torch.float64
P, R = 16, 64
MC = torch.float32  # Monte-Carlo dtype: fast, and z-scores are far above rounding


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# ------------------------------------------------------------------ resampling
@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_down_up_inverse(layout: Layout) -> None:
    x = torch.randn(3, 4, 8, generator=_gen(0))  # 4 coarse tokens
    assert torch.equal(down(up(x, layout), layout), x)
    y = torch.randn(3, P, 8, generator=_gen(1))
    proj = up(down(y, layout), layout)
    torch.testing.assert_close(up(down(proj, layout), layout), proj)  # idempotent
    assert down(y, layout).shape == (3, P // (2 if layout == "1d" else 4), 8)


def test_multi_level_1d() -> None:
    x = torch.randn(2, 4, 3, generator=_gen(2))
    assert torch.equal(down(up(x, "1d", 2), "1d", 2), x)
    y = torch.arange(16.0).reshape(1, 16, 1)
    assert down(y, "1d", 2).flatten().tolist() == [1.5, 5.5, 9.5, 13.5]


def test_2d_layout_is_row_major_grid() -> None:
    y = torch.arange(16.0).reshape(1, 16, 1)  # token i at row i // 4, column i % 4
    assert down(y, "2d").flatten().tolist() == [2.5, 4.5, 10.5, 12.5]
    coarse = torch.tensor([0.0, 1.0, 2.0, 3.0]).reshape(1, 4, 1)
    expected = [0, 0, 1, 1, 0, 0, 1, 1, 2, 2, 3, 3, 2, 2, 3, 3]
    assert up(coarse, "2d").flatten().tolist() == expected


# ------------------------------------------------------------------ constants
def test_paper_constants_for_2x2_blocks() -> None:
    for s in (0.1, 0.3, 0.5, 0.8):
        assert math.isclose(jump_end(s, 1 / 3), 2 * s / (1 + s))
        assert math.isclose(jump_alpha(s, 1 / 3), math.sqrt(3) * (1 - s) / 2)


def test_constants_for_pairs() -> None:
    s = 0.5
    assert math.isclose(jump_alpha(s, 1.0), (1 - s) / math.sqrt(2))
    assert math.isclose(jump_end(s, 1.0), math.sqrt(2) * s / (1 + (math.sqrt(2) - 1) * s))


@pytest.mark.parametrize(
    ("layout", "stages"), [("1d", 2), ("1d", 3), ("1d", 5), ("2d", 2), ("2d", 3)]
)
def test_windows_monotone(layout: Layout, stages: int) -> None:
    cfg = PyramidConfig(layout=layout, num_stages=stages)
    w = cfg.windows
    assert [x.stage for x in w] == list(range(stages, 0, -1))
    assert w[0].start == 0.0 and w[-1].end == 1.0
    for a, b in itertools.pairwise(w):
        assert 0 <= a.start < b.start < 1 and 0 < a.end < b.end <= 1
        assert a.end > b.start  # a jump re-noises: windows overlap
    assert all(x.start < x.end for x in w)


def test_default_windows_two_stages() -> None:
    w2 = PyramidConfig(layout="2d").windows
    assert math.isclose(w2[0].end, 2 / 3) and w2[1].start == 0.5
    w1 = PyramidConfig(layout="1d").windows
    assert math.isclose(w1[0].end, 2 - math.sqrt(2))  # sqrt(2)/2 / (1 + (sqrt(2)-1)/2)


def test_bad_settings_rejected() -> None:
    with pytest.raises(ValueError):
        PyramidConfig(layout="2d", g=1.0)  # Sigma' not PSD over 4 elements
    with pytest.raises(ValueError):
        PyramidConfig(layout="2d", num_stages=4)  # a 4x4 grid pools twice at most
    with pytest.raises(ValueError):
        stage_windows(2, 0.5, starts=(0.2, 0.5))
    with pytest.raises(ValueError):
        block_noise_from_white(torch.randn(2, 16, 1), "2d", 0.5)


# ------------------------------------------------------------------ block noise
@pytest.mark.parametrize(("layout", "g"), [("1d", 1.0), ("1d", 0.4), ("2d", 1 / 3), ("2d", 0.2)])
def test_block_noise_covariance(layout: Layout, g: float) -> None:
    z = torch.randn(20_000, P, 8, generator=_gen(3), dtype=F64)
    n = block_noise_from_white(z, layout, g)
    m = n.permute(0, 2, 1).reshape(-1, P)
    cov = m.T @ m / m.shape[0]
    b = 2 if layout == "1d" else 4
    block_id = up(torch.arange(P // b, dtype=F64).reshape(1, -1, 1), layout).flatten()
    same = block_id[:, None] == block_id[None, :]
    expected = torch.where(same, torch.full_like(cov, -g), torch.zeros_like(cov))
    expected.fill_diagonal_(1.0)
    assert (cov - expected).abs().max().item() < 0.02


# -------------------------------------------------------- the jump (Monte Carlo)
def _jump_discrepancy(
    layout: Layout,
    s: float,
    e: float,
    alpha: float,
    g: float,
    *,
    mean_scale: float | None = None,
    n: int = 50_000,
    width: int = 4,
    seed: int = 0,
) -> tuple[float, float, float]:
    """Max |z-score| of the mean and covariance of the post-jump state vs the start point.

    Returns (mean_z, cov_z, start_cov_z): the last one checks that the training start
    point (Eq. 6) itself has the analytic target statistics, so the two distributions
    agree. z-scores are errors divided by their Monte-Carlo standard deviation.
    """
    gen = _gen(seed)
    z1 = torch.randn(1, P, width, generator=gen, dtype=MC)
    coarse_w = StageWindow(stage=2, start=0.0, end=e)
    fine_w = StageWindow(stage=1, start=s, end=1.0)
    d = down(z1, layout)
    eps_c = torch.randn(n, d.shape[1], width, generator=gen, dtype=MC)
    z_end = stage_endpoints(d.expand(n, -1, -1), eps_c, coarse_w, layout)[1]  # Eq. 7, coarse
    z_s = jump(z_end, s=s, e=e, alpha=alpha, layout=layout, g=g, generator=gen)
    if mean_scale is not None:  # replace s/e by a wrong factor
        z_s = z_s + (mean_scale - s / e) * up(z_end, layout)
    eps_f = torch.randn(n, P, width, generator=gen, dtype=MC)
    start = stage_endpoints(z1.expand(n, -1, -1), eps_f, fine_w, layout)[0]  # Eq. 6, fine

    mean_target = s * up(d, layout)
    cov_target = (1 - s) ** 2 * torch.eye(P, dtype=MC)
    samples = n * width
    cov_sd = (1 - s) ** 2 * torch.where(torch.eye(P, dtype=torch.bool), math.sqrt(2), 1.0)
    cov_sd = cov_sd / math.sqrt(samples)

    def zscores(x: torch.Tensor) -> tuple[float, float]:
        dev = x - mean_target
        mean_z = dev.mean(0).abs().max().item() / ((1 - s) / math.sqrt(n))
        flat = dev.permute(0, 2, 1).reshape(-1, P)
        cov = flat.T @ flat / samples
        return mean_z, ((cov - cov_target).abs() / cov_sd).max().item()

    mean_z, cov_z = zscores(z_s)
    return mean_z, cov_z, zscores(start)[1]


Z_OK = 6.0  # null: max |z| over the ~200 statistics was 2.6-4.4 across 24 seeds
Z_FAIL = 15.0  # every wrong constant tried gives |z| > 40


@pytest.mark.parametrize(
    ("layout", "g", "s"),
    [
        ("1d", 1.0, 0.5),
        ("1d", 1.0, 0.25),
        ("2d", 1 / 3, 0.5),
        ("2d", 1 / 3, 0.7),
        ("2d", 0.2, 0.5),
        ("1d", 0.5, 0.5),
    ],
)
def test_jump_matches_training_start(layout: Layout, g: float, s: float) -> None:
    e, alpha = jump_end(s, g), jump_alpha(s, g)
    mean_z, cov_z, start_z = _jump_discrepancy(layout, s, e, alpha, g)
    assert mean_z < Z_OK and cov_z < Z_OK and start_z < Z_OK, (mean_z, cov_z, start_z)


def test_jump_wrong_alpha_detected() -> None:
    for layout, g in (("1d", 1.0), ("2d", 1 / 3)):
        s = 0.5
        e, alpha = jump_end(s, g), jump_alpha(s, g)
        for factor in (0.9, 1.1):
            _, cov_z, _ = _jump_discrepancy(layout, s, e, factor * alpha, g)
            assert cov_z > Z_FAIL, (layout, factor, cov_z)


def test_jump_2x2_constants_with_pair_noise_detected() -> None:
    """The paper's b = 4 constants on a 1-D pyramid (b = 2, default g = 1) are wrong."""
    s = 0.5
    _, cov_z, _ = _jump_discrepancy("1d", s, 2 * s / (1 + s), math.sqrt(3) * (1 - s) / 2, 1.0)
    assert cov_z > Z_FAIL


def test_jump_pair_constants_on_grid_detected() -> None:
    s = 0.5
    _, cov_z, _ = _jump_discrepancy("2d", s, jump_end(s, 1.0), jump_alpha(s, 1.0), 1 / 3)
    assert cov_z > Z_FAIL


def test_jump_paper_constants_with_g_02_detected() -> None:
    """Sigma' with g = 0.2 needs its own e and alpha, not the g = 1/3 ones."""
    s = 0.5
    _, cov_z, _ = _jump_discrepancy("2d", s, 2 * s / (1 + s), math.sqrt(3) * (1 - s) / 2, 0.2)
    assert cov_z > Z_FAIL


def test_jump_wrong_mean_scale_detected() -> None:
    s, g = 0.5, 1 / 3
    mean_z, _, _ = _jump_discrepancy("2d", s, jump_end(s, g), jump_alpha(s, g), g, mean_scale=1.0)
    assert mean_z > Z_FAIL


def test_constants_depend_on_g_not_b() -> None:
    """g = 1/3 is admissible for pairs too: its (e, alpha) work there (less efficiently)."""
    s, g = 0.5, 1 / 3
    mean_z, cov_z, _ = _jump_discrepancy("1d", s, jump_end(s, g), jump_alpha(s, g), g)
    assert mean_z < Z_OK and cov_z < Z_OK


# ------------------------------------------------------------------ training
@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_training_sample_structure(layout: Layout) -> None:
    cfg = PyramidConfig(layout=layout)
    z1 = torch.randn(256, P, R, generator=_gen(4), dtype=F64)
    smp = pyramid_training_sample(z1, cfg, generator=_gen(5))
    assert smp.x.shape == smp.target.shape == z1.shape
    assert smp.t.shape == smp.t_local.shape == smp.stage.shape == (256,)
    assert smp.mask.shape == (256, P)
    counts = torch.bincount(smp.stage, minlength=3)[1:]
    assert counts.min().item() > 90  # both stages drawn
    tl = smp.t_local[:, None, None]
    start = smp.x - tl * smp.target
    end = smp.x + (1 - tl) * smp.target
    for w in cfg.windows:
        sel = smp.stage == w.stage
        n_tok = cfg.tokens(w.stage)
        assert bool(smp.mask[sel, :n_tok].all()) and not bool(smp.mask[sel, n_tok:].any())
        assert bool((smp.x[sel, n_tok:] == 0).all() and (smp.target[sel, n_tok:] == 0).all())
        t = smp.t[sel]
        assert bool(((t >= w.start) & (t <= w.end)).all())
        torch.testing.assert_close(t, w.start + smp.t_local[sel] * (w.end - w.start))
        st, en = start[sel, :n_tok], end[sel, :n_tok]
        data = down(z1[sel], layout, w.level)
        if w.stage == cfg.num_stages:  # coarsest: start is pure noise eps
            torch.testing.assert_close(en - w.end * data, (1 - w.end) * st)
        else:  # finest: ends at the data; start = s Up(Down z1) + (1 - s) eps
            torch.testing.assert_close(en, data)
            eps = (st - w.start * up(down(data, layout), layout)) / (1 - w.start)
            assert abs(eps.std().item() - 1.0) < 0.02


def test_training_sample_forced_stage_and_determinism() -> None:
    cfg = PyramidConfig(layout="2d")
    z1 = torch.randn(8, P, R, generator=_gen(6))
    a = pyramid_training_sample(z1, cfg, stage=2, generator=_gen(7))
    b = pyramid_training_sample(z1, cfg, stage=2, generator=_gen(7))
    c = pyramid_training_sample(z1, cfg, stage=2, generator=_gen(8))
    assert bool((a.stage == 2).all()) and int(a.mask.sum()) == 8 * 4
    for f in ("x", "t", "target", "mask"):
        assert torch.equal(getattr(a, f), getattr(b, f))
    assert not torch.equal(a.x, c.x)
    with pytest.raises(ValueError):
        pyramid_training_sample(z1, cfg, stage=3)


def test_loss_uses_mask() -> None:
    cfg = PyramidConfig()
    z1 = torch.randn(16, P, R, generator=_gen(9))
    smp = pyramid_training_sample(z1, cfg, generator=_gen(10))
    pred = smp.target + torch.where(smp.mask[..., None], 0.0, 1e3)
    assert flow_matching_loss(pred, smp.target, smp.mask).item() == 0.0


def test_no_pyramid_is_plain_flow_matching() -> None:
    cfg = PyramidConfig(num_stages=1)
    assert cfg.windows == (StageWindow(stage=1, start=0.0, end=1.0),)
    z1 = torch.randn(4, P, R, generator=_gen(11))
    smp = pyramid_training_sample(z1, cfg, generator=_gen(12))
    assert bool(smp.mask.all()) and torch.equal(smp.t, smp.t_local)
    t = smp.t[:, None, None]
    torch.testing.assert_close(smp.x + (1 - t) * smp.target, z1)  # ends at the data
    eps = smp.x - t * smp.target  # starts at pure noise
    assert abs(eps.std().item() - 1.0) < 0.05 and abs(eps.mean().item()) < 0.05


# ------------------------------------------------------------------ sampling
def _delta_oracle(z1: torch.Tensor, cfg: PyramidConfig, seen: list[tuple[int, float]]) -> Any:
    """Exact marginal velocity when the data distribution is a point mass at z1.

    Inside stage k the state is m(t') + sigma(t') eps with
    m = t' e D_k + (1 - t') s Up(Down(D_k)), sigma = t'(1-e) + (1-t')(1-s), so eps is
    recoverable from the state and the velocity end - start is exact.
    """

    def v(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor) -> torch.Tensor:
        k = int(stage[0])
        w = cfg.window(k)
        tl = float((t[0] - w.start) / (w.end - w.start))
        seen.append((k, float(t[0])))
        data = down(z1, cfg.layout, w.level)
        coarse = up(down(data, cfg.layout), cfg.layout) if w.start > 0 else 0.0 * data
        m = tl * w.end * data + (1 - tl) * w.start * coarse
        sigma = tl * (1 - w.end) + (1 - tl) * (1 - w.start)
        eps = (x - m) / sigma
        return w.end * data - w.start * coarse + (w.start - w.end) * eps

    return v


@pytest.mark.parametrize(("layout", "stages"), [("1d", 2), ("2d", 2), ("1d", 3), ("1d", 1)])
def test_sampler_with_oracle_recovers_data(layout: Layout, stages: int) -> None:
    cfg = PyramidConfig(layout=layout, num_stages=stages)
    z1 = torch.randn(3, P, 8, generator=_gen(13), dtype=F64)
    seen: list[tuple[int, float]] = []
    noise = initial_noise(cfg, 3, 8, generator=_gen(14), dtype=F64)
    steps = default_steps(stages)
    out = sample_pyramid(_delta_oracle(z1, cfg, seen), noise, cfg, steps=steps, generator=_gen(15))
    assert out.x.shape == z1.shape and out.nfe == sum(steps) == len(seen)
    torch.testing.assert_close(out.x, z1, atol=1e-9, rtol=0)
    # the model saw the stages coarse -> fine, with times inside each window
    assert [k for k, _ in seen] == sorted((k for k, _ in seen), reverse=True)
    for k, t in seen:
        w = cfg.window(k)
        assert w.start - 1e-12 <= t <= w.end


def test_sampler_steps_and_determinism() -> None:
    cfg = PyramidConfig(layout="2d")
    assert default_steps(2) == (45, 5)  # the paper's split
    assert default_steps(1) == (50,) and default_steps(1, 7) == (7,)
    assert default_steps(2, 9) == (5, 4)  # not 50 steps: an even split, coarse first
    assert default_steps(3) == (17, 17, 16) and default_steps(4, 10) == (3, 3, 2, 2)

    def v(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor, scale: float) -> torch.Tensor:
        return -scale * x

    noise = initial_noise(cfg, 2, R, generator=_gen(16))
    assert noise.shape == (2, 4, R)
    a = sample_pyramid(v, noise, cfg, method="heun", generator=_gen(17), cond={"scale": 0.1})
    b = sample_pyramid(v, noise, cfg, method="heun", generator=_gen(17), cond={"scale": 0.1})
    c = sample_pyramid(v, noise, cfg, method="heun", generator=_gen(18), cond={"scale": 0.1})
    assert a.x.shape == (2, P, R) and a.nfe == 2 * 50
    assert torch.equal(a.x, b.x) and not torch.equal(a.x, c.x)
    with pytest.raises(ValueError):
        sample_pyramid(v, noise, cfg, steps=(10,), cond={"scale": 0.1})


@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_the_sampler_jumps_to_the_finer_stages_training_start(layout: Layout) -> None:
    """Inside sample_pyramid (not the jump function alone): with the exact velocity of a
    point mass at z1, the state the fine stage first sees must have the mean s Up(Down z1)
    and covariance (1 - s)^2 I of its training start. A sampler that re-noised with another
    alpha (half of it: cov z ~ 10^3) or mean factor fails; the oracle recovery test
    above cannot see either, since the oracle ends at the data from any start."""
    cfg = PyramidConfig(layout=layout, num_stages=2)
    n, width = 512, 8
    z1 = torch.randn(1, P, width, generator=_gen(21), dtype=MC)
    first_fine: list[torch.Tensor] = []
    oracle = _delta_oracle(z1.expand(n, -1, -1), cfg, [])

    def v(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor) -> torch.Tensor:
        if int(stage[0]) == 1 and not first_fine:
            first_fine.append(x.clone())
        return oracle(x, t, stage=stage)

    noise = initial_noise(cfg, n, width, generator=_gen(22), dtype=MC)
    out = sample_pyramid(v, noise, cfg, steps=(8, 2), generator=_gen(23))
    torch.testing.assert_close(out.x, z1.expand(n, -1, -1), atol=1e-4, rtol=0)
    s = cfg.window(1).start
    dev = first_fine[0] - s * up(down(z1, layout), layout)
    samples = n * width
    mean_z = dev.mean(0).abs().max().item() / ((1 - s) / math.sqrt(n))
    flat = dev.permute(0, 2, 1).reshape(-1, P)
    cov = flat.T @ flat / samples
    cov_sd = (1 - s) ** 2 * torch.where(torch.eye(P, dtype=torch.bool), math.sqrt(2), 1.0)
    cov_z = ((cov - (1 - s) ** 2 * torch.eye(P)).abs() / (cov_sd / math.sqrt(samples))).max()
    assert mean_z < Z_OK and float(cov_z) < Z_OK, (mean_z, float(cov_z))


# ------------------------------------------------- exact values, defaults, messages
def _refused(message: str) -> Any:
    """pytest.raises for a ValueError whose whole text is ``message``."""
    return pytest.raises(ValueError, match="^" + re.escape(message) + "$")


def test_resampling_functions_default_to_one_level() -> None:
    y = torch.arange(16.0).reshape(1, 16, 1)
    assert down_1d(y).flatten().tolist() == [0.5 + 2 * i for i in range(8)]
    assert down_2d(y).flatten().tolist() == [2.5, 4.5, 10.5, 12.5]
    c = torch.arange(4.0).reshape(1, 4, 1)
    assert up_1d(c).flatten().tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    assert up_2d(c).flatten().tolist() == [0, 0, 1, 1, 0, 0, 1, 1, 2, 2, 3, 3, 2, 2, 3, 3]


@pytest.mark.parametrize("fn", [down_1d, up_1d, down_2d, up_2d])
def test_zero_levels_return_the_input_itself(fn: Any) -> None:
    x = torch.randn(2, 16, 3, generator=_gen(30))
    assert fn(x, 0) is x


def test_down_1d_pairs_the_token_axis_whatever_the_leading_dims() -> None:
    y = torch.arange(8.0).reshape(4, 2)  # no batch axis: 4 tokens of 2 channels
    assert down_1d(y).tolist() == [[1.0, 2.0], [5.0, 6.0]]
    z = torch.arange(32.0).reshape(2, 2, 4, 2)  # two leading axes
    torch.testing.assert_close(down_1d(z), (z[..., 0::2, :] + z[..., 1::2, :]) / 2)


def test_up_repeats_2_to_the_levels_tokens() -> None:
    c = torch.tensor([[[0.0], [1.0]]])
    assert up_1d(c, 3).flatten().tolist() == [0.0] * 8 + [1.0] * 8  # 2^3, not 2 * 3
    assert up(c, "1d", 3).shape == (1, 16, 1)
    one = torch.tensor([[[5.0, -1.0]]])  # a 1x1 grid
    assert up(one, "2d", 2).shape == (1, 16, 2)  # two 2x upsamplings: 1 -> 4 -> 16 tokens
    x = torch.randn(2, 4, 3, generator=_gen(31))
    torch.testing.assert_close(up(x, "2d", 2), up(up(x, "2d"), "2d"), atol=0, rtol=0)
    assert torch.equal(down(up(x, "2d", 2), "2d", 2), x)


def test_resampling_refuses_bad_token_counts_by_name() -> None:
    with _refused("2-D layout needs an even square token count, got 8"):
        down(torch.zeros(1, 8, 1), "2d")  # not a square
    with _refused("2-D layout needs an even square token count, got 9"):
        down(torch.zeros(1, 9, 1), "2d")  # an odd side cannot pool 2x2
    with _refused("2-D layout needs a square token count, got 8"):
        up(torch.zeros(1, 8, 1), "2d")
    with _refused("cannot halve 5 tokens"):
        down(torch.zeros(1, 5, 1), "1d")
    with _refused("unknown layout '3d'"):
        block_size("3d")  # type: ignore[arg-type]
    with _refused("block size must be >= 2, got 1"):
        max_correlation(1)


def test_correlation_bounds_are_inclusive_with_a_rounding_tolerance() -> None:
    check_correlation(0.0, 4)  # g = 0: Sigma' = I, independent noise is admissible
    check_correlation(1 / 3, 4)
    check_correlation(max_correlation(4) + pyr._G_TOL, 4)  # 1/3 rounded up is still 1/3
    with _refused("g=0.3333333353 outside [0, 0.333333] for block size 4"):
        check_correlation(round(1 / 3 + 2e-9, 10), 4)
    with _refused("g=-0.1 outside [0, 1] for block size 2"):
        check_correlation(-0.1, 2)
    with _refused("g=0.5 outside [0, 0.333333] for block size 4"):
        PyramidConfig(layout="2d", g=0.5)


def test_jump_end_refuses_starts_outside_the_open_unit_interval() -> None:
    for s in (0.0, 1.0, 1.5, -0.2):
        with _refused(f"start of the finer stage must lie in (0, 1), got {s}"):
            jump_end(s, 1 / 3)


def test_stage_windows_messages_and_strictly_increasing_starts() -> None:
    with _refused("num_stages must be >= 1, got 0"):
        stage_windows(0, 1.0)
    with _refused("starts must be 2 increasing values from 0, got [0.2, 0.5]"):
        stage_windows(2, 0.5, starts=(0.2, 0.5))
    with _refused("starts must be 3 increasing values from 0, got [0.0, 0.5, 0.5]"):
        stage_windows(3, 1 / 3, starts=(0.0, 0.5, 0.5))  # two stages may not share a start
    w = stage_windows(3, 1 / 3, starts=(0.0, 0.25, 0.5))
    assert [x.start for x in w] == [0.0, 0.25, 0.5]
    assert [x.end for x in w] == [jump_end(0.25, 1 / 3), jump_end(0.5, 1 / 3), 1.0]


def test_config_validates_at_construction() -> None:
    with _refused("num_stages must be >= 1, got 0"):
        PyramidConfig(num_stages=0)
    with _refused("16 tokens cannot form a 4-stage grid"):
        PyramidConfig(layout="2d", num_stages=4)
    with _refused("15 tokens cannot be halved 1 times"):
        PyramidConfig(num_tokens=15)
    with _refused("12 tokens cannot be halved 3 times"):
        PyramidConfig(num_tokens=12, num_stages=4)  # 12 -> 6 -> 3 -> (1.5)
    with _refused("starts must be 2 increasing values from 0, got [0.2, 0.5]"):
        PyramidConfig(starts=(0.2, 0.5))  # bad starts are refused before .windows is read
    flat = PyramidConfig(layout="2d", num_stages=1)  # no pyramid on a grid
    assert flat.tokens(1) == 16 and flat.windows == (StageWindow(1, 0.0, 1.0),)
    deep = PyramidConfig(layout="2d", num_stages=4, num_tokens=64)  # an 8x8 grid pools 3x
    assert [deep.tokens(k) for k in (1, 2, 3, 4)] == [64, 16, 4, 1]
    assert PyramidConfig(num_tokens=12, num_stages=3).tokens(3) == 3
    white = PyramidConfig(g=0.0)  # independent noise: the coarse stage runs to the data
    assert white.correlation == 0.0 and white.windows[0].end == 1.0


def test_block_noise_from_white_hand_values() -> None:
    z = torch.tensor([[[1.0], [3.0]]], dtype=F64)  # one pair: mean 2, detail -1, +1
    n = block_noise_from_white(z, "1d", 0.5)
    keep = math.sqrt(1 - 0.5)
    assert n.flatten().tolist() == pytest.approx(
        [-math.sqrt(1.5) + 2 * keep, math.sqrt(1.5) + 2 * keep], abs=1e-15
    )
    z = torch.tensor([[[1.0], [2.0], [3.0], [6.0]]], dtype=F64)  # one 2x2 cell, mean 3
    n = block_noise_from_white(z, "2d", 0.2)
    want = [math.sqrt(1.2) * d + math.sqrt(1 - 3 * 0.2) * 3 for d in (-2.0, -1.0, 0.0, 3.0)]
    assert n.flatten().tolist() == pytest.approx(want, abs=1e-15)
    white = torch.randn(2, P, 3, generator=_gen(32), dtype=F64)
    torch.testing.assert_close(block_noise_from_white(white, "2d", 0.0), white)  # g = 0: I


@pytest.mark.parametrize(("layout", "g"), [("1d", 1.0), ("2d", 0.2)])
def test_block_noise_and_jump_replay_the_generator_in_the_states_dtype(
    layout: Layout, g: float
) -> None:
    n = block_noise((2, P, 3), layout, g, generator=_gen(33), dtype=F64)
    white = torch.randn(2, P, 3, generator=_gen(33), dtype=F64)
    assert n.dtype == F64
    torch.testing.assert_close(n, block_noise_from_white(white, layout, g), atol=0, rtol=0)

    b = 2 if layout == "1d" else 4
    z_end = torch.randn(3, P // b, 5, generator=_gen(34), dtype=F64)
    s = 0.4
    e, alpha = jump_end(s, g), jump_alpha(s, g)
    out = jump(z_end, s=s, e=e, alpha=alpha, layout=layout, g=g, generator=_gen(35))
    white = torch.randn(3, P, 5, generator=_gen(35), dtype=F64)
    want = (s / e) * up(z_end, layout) + alpha * block_noise_from_white(white, layout, g)
    assert out.dtype == F64
    torch.testing.assert_close(out, want, atol=1e-14, rtol=0)


def test_initial_noise_is_the_generators_first_draw_at_the_coarsest_resolution() -> None:
    cfg = PyramidConfig(num_stages=3)
    noise = initial_noise(cfg, 2, 5, generator=_gen(36), dtype=F64)
    assert noise.dtype == F64 and noise.shape == (2, 4, 5)
    want = torch.randn(2, 4, 5, generator=_gen(36), dtype=F64)
    torch.testing.assert_close(noise, want, atol=0, rtol=0)
    assert initial_noise(cfg, 1, 5).dtype == torch.float32


@pytest.mark.parametrize(
    ("kwargs", "loc", "scale"),
    [
        ({}, None, None),  # uniform
        ({"time_distribution": "logit_normal"}, 0.0, 1.0),  # the distribution's defaults
        ({"time_distribution": "logit_normal", "time_loc": 0.4, "time_scale": 2.0}, 0.4, 2.0),
    ],
)
def test_training_sample_replays_stages_then_times_then_noise(
    kwargs: dict[str, Any], loc: float | None, scale: float | None
) -> None:
    """One generator, drawn in the documented order: the stages, t', then one noise eps of
    the full shape (its first tokens serve the coarser stages), all in z1's dtype."""
    cfg = PyramidConfig(layout="1d", num_stages=3)
    batch = 12
    z1 = torch.randn(batch, P, 4, generator=_gen(40), dtype=F64)
    smp = pyramid_training_sample(z1, cfg, generator=_gen(41), **kwargs)
    twin = _gen(41)
    stages = torch.randint(1, 4, (batch,), generator=twin)
    if loc is None:
        t_local = torch.rand(batch, generator=twin, dtype=F64)
    else:
        assert scale is not None
        t_local = torch.sigmoid(loc + scale * torch.randn(batch, generator=twin, dtype=F64))
    eps = torch.randn(z1.shape, generator=twin, dtype=F64)
    assert smp.stage.dtype == torch.long and torch.equal(smp.stage, stages)
    assert set(stages.tolist()) == {1, 2, 3}
    assert smp.t_local.dtype == smp.t.dtype == smp.x.dtype == F64
    torch.testing.assert_close(smp.t_local, t_local, atol=0, rtol=0)
    for i in range(batch):
        w = cfg.window(int(stages[i]))
        n = cfg.tokens(w.stage)
        x_level = down(z1[i : i + 1], "1d", w.level)
        start, end = stage_endpoints(x_level, eps[i : i + 1, :n], w, "1d")
        tl = float(t_local[i])
        torch.testing.assert_close(smp.x[i, :n], (tl * end + (1 - tl) * start)[0])
        torch.testing.assert_close(smp.target[i, :n], (end - start)[0])
        assert float(smp.t[i]) == pytest.approx(w.start + tl * (w.end - w.start), abs=1e-15)


def test_training_sample_forced_stages() -> None:
    cfg = PyramidConfig(layout="1d")
    z1 = torch.randn(3, P, 4, generator=_gen(42), dtype=F64)
    fine = pyramid_training_sample(z1, cfg, stage=1, generator=_gen(43))  # the finest only
    assert fine.stage.tolist() == [1, 1, 1] and bool(fine.mask.all())
    assert bool((fine.target != 0).all())
    t = fine.t_local[:, None, None]
    torch.testing.assert_close(fine.x + (1 - t) * fine.target, z1)  # ends at the data
    # a per-sample stage tensor (any integer dtype) with one sample alone in its stage
    mixed = pyramid_training_sample(
        z1, cfg, stage=torch.tensor([2, 1, 2], dtype=torch.int32), generator=_gen(44)
    )
    assert mixed.stage.dtype == torch.long and mixed.stage.tolist() == [2, 1, 2]
    assert mixed.mask.sum(1).tolist() == [8, 16, 8]
    assert bool((mixed.target[1] != 0).all())
    for bad in (0, 3):
        with _refused("stage must lie in [1, 2]"):
            pyramid_training_sample(z1, cfg, stage=bad)
    with _refused("expected 16 tokens, got 8"):
        pyramid_training_sample(z1[:, :8], cfg)


@pytest.mark.parametrize(("layout", "stages"), [("1d", 5), ("2d", 3)])
def test_training_at_a_single_token_coarsest_stage(layout: Layout, stages: int) -> None:
    """The coarsest stage starts at pure noise (s = 0), so it never pools its one token."""
    cfg = PyramidConfig(layout=layout, num_stages=stages)
    assert cfg.tokens(stages) == 1
    z1 = torch.randn(4, P, 3, generator=_gen(45), dtype=F64)
    smp = pyramid_training_sample(z1, cfg, stage=stages, generator=_gen(46))
    assert smp.mask.sum(1).tolist() == [1] * 4
    w = cfg.window(stages)
    coarsest = down(z1, layout, stages - 1)
    start, end = stage_endpoints(coarsest, torch.zeros(4, 1, 3, dtype=F64), w, layout)
    assert torch.equal(start, torch.zeros(4, 1, 3, dtype=F64))
    assert torch.equal(end, w.end * coarsest)


def test_sampler_messages() -> None:
    cfg = PyramidConfig(layout="1d")

    def v(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor) -> torch.Tensor:
        return x

    with _refused("need 2 step counts (coarse -> fine), got (10,)"):
        sample_pyramid(v, torch.zeros(1, 8, 2), cfg, steps=(10,))
    with _refused("initial noise must have 8 tokens"):
        sample_pyramid(v, torch.zeros(1, 16, 2), cfg)


def test_three_stage_sampler_jumps_with_each_next_stages_start() -> None:
    """With a zero velocity the sampler is its jumps alone: stage k's end state (the noise)
    is scaled by s_{k-1}/e_k, upsampled and re-noised with alpha(s_{k-1}) block noise drawn
    from the generator, every stage seeing its own index and global times."""
    cfg = PyramidConfig(layout="1d", num_stages=3)  # g = 1, starts 0, 1/3, 2/3
    noise = initial_noise(cfg, 2, 3, generator=_gen(50), dtype=F64)
    seen: list[tuple[int, float]] = []

    def still(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor) -> torch.Tensor:
        assert stage.dtype == torch.long and stage.shape == (2,)
        seen.append((int(stage[0]), float(t[0])))
        return torch.zeros_like(x)

    out = sample_pyramid(still, noise, cfg, steps=(2, 1, 2), generator=_gen(51))
    twin = _gen(51)
    x = noise
    w3, w2, w1 = cfg.windows
    assert (w2.start, w1.start) == (1 / 3, 2 / 3)
    for w, s in ((w3, 1 / 3), (w2, 2 / 3)):
        x_up = up(x, "1d")
        white = torch.randn(x_up.shape, generator=twin, dtype=F64)
        detail = white - up(down(white, "1d"), "1d")
        x = (s / w.end) * x_up + (1 - s) / math.sqrt(2) * (math.sqrt(2) * detail)
    assert out.nfe == 5 and out.x.dtype == F64
    torch.testing.assert_close(out.x, x, atol=1e-12, rtol=0)
    want = [(3, 0.0), (3, 0.5 * w3.end), (2, w2.start), (1, w1.start), (1, w1.start + 0.5 / 3)]
    assert [k for k, _ in seen] == [k for k, _ in want]
    assert [t for _, t in seen] == pytest.approx([t for _, t in want], abs=1e-7)
