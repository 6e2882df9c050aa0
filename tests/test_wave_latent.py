"""research/wave_latent.py: how a latent changes along time, and a swing's frequency."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_script


def test_wave_latent_measures_change_along_time():
    wl = load_script("wave_latent")
    still = torch.ones(3, 8, 4)
    assert wl.time_variation(still) == (0.0, 0.0)
    alt = torch.tensor([1.0, -1.0] * 4)[None, :, None].expand(2, 8, 4)  # +1 -1 +1 ...
    step, spread = wl.time_variation(alt)
    assert step == 4.0 and spread == 1.0
    assert torch.equal(wl.pair_mean(alt), torch.zeros_like(alt))  # the pairs cancel
    ramp = torch.arange(8.0)[None, :, None]
    assert wl.pair_mean(ramp).flatten().tolist() == [0.5, 0.5, 2.5, 2.5, 4.5, 4.5, 6.5, 6.5]
    assert torch.equal(wl.time_mean(ramp), torch.full_like(ramp, 3.5))
    assert wl.time_variation(wl.time_mean(ramp)) == (0.0, 0.0)
    t = np.arange(150) / 30.0
    assert wl.swing_frequency(0.2 * np.sin(2 * np.pi * 1.2 * t) + 0.5 * t) == pytest.approx(1.2)


def test_detail_retention_compares_fine_detail_only():
    wl = load_script("wave_latent")
    g = torch.Generator().manual_seed(0)
    truth = torch.randn(4, 8, 3, generator=g)
    assert wl.detail_retention(truth, truth) == pytest.approx((1.0, 1.0))
    coarse = wl.pair_mean(truth)
    assert wl.detail_retention(coarse, truth) == pytest.approx((0.0, 0.0), abs=1e-12)
    half = coarse + 0.5 * (truth - coarse)  # half the detail, whatever the pair means do
    assert wl.detail_retention(half + 3.0, truth) == pytest.approx((0.25, 0.5))
    flipped = coarse - (truth - coarse)  # as much detail, the wrong way round
    assert wl.detail_retention(flipped, truth) == pytest.approx((1.0, -1.0))


def test_nearest_finds_the_real_latent_a_sample_copies():
    wl = load_script("wave_latent")
    g = torch.Generator().manual_seed(0)
    ref = torch.randn(5, 8, 3, generator=g)
    near = ref[[3, 0, 3]] + 0.01 * torch.randn(3, 8, 3, generator=g)  # near-copies
    dist, which = wl.nearest(near, ref)
    assert which.tolist() == [3, 0, 3]
    assert float(dist.max()) < 1e-3  # per element: about 0.01² each
    far = torch.zeros(1, 8, 3)  # the origin: nearest is the smallest latent, at its norm
    dist, which = wl.nearest(far, ref)
    norms = ref.flatten(1).pow(2).mean(1)
    assert int(which) == int(norms.argmin()) and float(dist) == pytest.approx(float(norms.min()))


@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_stage_noise_estimate_recovers_the_noise_on_every_stage(layout):
    """On each stage's path, with the exact target as the velocity, the estimate is the
    noise the state was built from (a wrong A, B, C or S for either component fails)."""
    from umf.flows.pyramid import PyramidConfig, down, stage_endpoints

    wl = load_script("wave_latent")
    cfg = PyramidConfig(layout=layout, num_stages=3, num_tokens=16)
    g = torch.Generator().manual_seed(0)
    z1 = torch.randn(4, 16, 5, generator=g)
    for w in cfg.windows:
        x_level = down(z1, layout, w.level)
        eps = torch.randn(x_level.shape, generator=g)
        start, end = stage_endpoints(x_level, eps, w, layout)
        for t in (0.0, 0.3, 0.9):
            x = t * end + (1 - t) * start
            est, scale = wl.stage_noise_estimate(x, end - start, t, w, layout)
            assert torch.allclose(est, eps, atol=1e-5), (w, t)
            assert scale == pytest.approx(t * (1 - w.end) + (1 - t) * (1 - w.start))


def _gaussian_pyramid_field(cfg, var: float):
    """The exact velocity of a pyramid's paths for i.i.d. N(0, var) latents: per stage and
    component (block means, detail), x = A X + S eps and v = B X + C eps with X and eps
    independent Gaussians, so E[v | x] = (B A var_X + C S) / (A^2 var_X + S^2) x."""
    from umf.flows.pyramid import split_detail

    def field(x, t, *, stage):
        w = cfg.window(int(stage[0]))
        tl = (float(t[0]) - w.start) / (w.end - w.start)
        s, e = w.start, w.end
        var_x = var / cfg.block**w.level  # Down averages blocks of independent tokens
        scale, c = tl * (1 - e) + (1 - tl) * (1 - s), s - e
        parts = [(x, tl * e + (1 - tl) * s, e - s)]
        if s > 0:
            mean, detail = split_detail(x, cfg.layout)
            parts = [(mean, tl * e + (1 - tl) * s, e - s), (detail, tl * e, e)]
        return sum((b * a * var_x + c * scale) / (a * a * var_x + scale**2) * xx
                   for xx, a, b in parts)  # fmt: skip

    return field


@pytest.mark.parametrize("churn", [(0.0, 0.0), (2.0, 2.0), (0.0, 8.0)])
def test_churn_sampler_keeps_the_data_distribution_with_the_exact_field(churn):
    """With the exact field, Langevin churn must not change what is sampled: Gaussian data
    of variance 4 come out with variance 4 (a wrong sign of the Langevin term or a wrong
    noise scale moves it far off)."""
    from umf.flows.pyramid import PyramidConfig, initial_noise

    wl = load_script("wave_latent")
    cfg = PyramidConfig(layout="1d", num_stages=2, num_tokens=8)
    g = torch.Generator().manual_seed(0)
    noise = initial_noise(cfg, 2000, 1, generator=g)
    x = wl.churn_sample(_gaussian_pyramid_field(cfg, 4.0), cfg, noise, churn, (200, 200), g)
    assert x.shape == (2000, 8, 1)
    assert float(x.var()) == pytest.approx(4.0, rel=0.06)
    detail = x - wl.pair_mean(x)  # the fine stage's own part: variance 4 * 1/2
    assert float(detail.var()) == pytest.approx(2.0, rel=0.06)


def test_churn_sampler_without_churn_is_the_pyramid_sampler():
    """Churn 0 must take exactly sample_pyramid's Euler steps and jumps (the same field,
    noise and generator): the script's copy of the stage loop may not drift from it."""
    from umf.flows.pyramid import PyramidConfig, initial_noise, sample_pyramid

    wl = load_script("wave_latent")
    cfg = PyramidConfig(layout="1d", num_stages=3, num_tokens=16)

    def field(x, t, *, stage):  # nonlinear in x, t and the stage
        return torch.tanh(x * (1.0 + t[:, None, None])) - 0.3 * stage[:, None, None] * x

    noise = initial_noise(cfg, 6, 4, generator=torch.Generator().manual_seed(0))
    ours = wl.churn_sample(field, cfg, noise, (0.0,) * 3, (7, 5, 3),
                           torch.Generator().manual_seed(1))  # fmt: skip
    theirs = sample_pyramid(field, noise, cfg, steps=(7, 5, 3), method="euler",
                            generator=torch.Generator().manual_seed(1)).x  # fmt: skip
    assert torch.allclose(ours, theirs, atol=1e-6)
    other = sample_pyramid(field, noise, cfg, steps=(7, 5, 3),
                           generator=torch.Generator().manual_seed(2)).x  # fmt: skip
    assert not torch.allclose(ours, other, atol=1e-3)  # the jumps' noise matters
