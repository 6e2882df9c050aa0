"""S-Flow semi-noise joint path: state, targets, losses and the sampler."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from umf.flows import (
    sample_semi_noise,
    semi_noise_initial_state,
    semi_noise_loss,
    semi_noise_state,
    semi_noise_training_sample,
    split_halves,
    warm_state,
)

F64 = torch.float64
B, P, R = 4, 16, 64


def _data(seed: int = 0, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    c, w, eps = (torch.randn(B, P, R, generator=g, dtype=dtype) for _ in range(3))
    return c, w, eps


def test_state_shapes_and_layout() -> None:
    c, w, eps = _data()
    s = semi_noise_state(c, w, eps, torch.rand(B))
    assert s.x.shape == s.target.shape == (B, P, 2 * R) and s.t.shape == (B,)
    ctx_t, react_t = split_halves(s.target)
    torch.testing.assert_close(ctx_t, c - eps)
    torch.testing.assert_close(react_t, w - c)
    r = semi_noise_state(c, w, eps, torch.rand(B), reaction_only=True)
    assert r.x.shape == r.target.shape == (B, P, R)
    torch.testing.assert_close(r.target, w - c)


def test_endpoints() -> None:
    c, w, eps = _data(1)
    at0 = semi_noise_state(c, w, eps, torch.zeros(B)).x
    at1 = semi_noise_state(c, w, eps, torch.ones(B)).x
    assert torch.equal(at0, torch.cat([eps, c], -1))
    assert torch.equal(at1, torch.cat([c, w], -1))
    assert torch.equal(semi_noise_initial_state(c, noise=eps), at0)
    assert torch.equal(semi_noise_initial_state(c, reaction_only=True), c)
    only = semi_noise_state(c, w, eps, torch.zeros(B), reaction_only=True).x
    assert torch.equal(only, c)


@pytest.mark.parametrize("reaction_only", [False, True])
def test_target_is_finite_difference(reaction_only: bool) -> None:
    c, w, eps = _data(2, F64)
    t = torch.tensor([0.05, 0.3, 0.6, 0.95], dtype=F64)
    h = 1e-6

    def state(tt: torch.Tensor) -> torch.Tensor:
        return semi_noise_state(c, w, eps, tt, reaction_only=reaction_only).x

    fd = (state(t + h) - state(t - h)) / (2 * h)
    target = semi_noise_state(c, w, eps, t, reaction_only=reaction_only).target
    torch.testing.assert_close(fd, target, atol=1e-8, rtol=0)


def test_loss_weights_and_ablations() -> None:
    c, w, eps = _data(3)
    s = semi_noise_state(c, w, eps, torch.rand(B))
    ctx_err = torch.zeros_like(c) + 1.0  # recon MSE 1
    react_err = torch.zeros_like(c) + 2.0  # reaction MSE 4
    pred = s.target + torch.cat([ctx_err, react_err], -1)
    full = semi_noise_loss(pred, s.target, lambda_recon=0.5)
    assert full.reaction.item() == pytest.approx(4.0)
    assert full.recon.item() == pytest.approx(1.0)
    assert full.total.item() == pytest.approx(4.5)
    no_recon = semi_noise_loss(pred, s.target, lambda_recon=0.0)
    assert no_recon.total.item() == pytest.approx(4.0)
    r = semi_noise_state(c, w, eps, torch.rand(B), reaction_only=True)
    only = semi_noise_loss(r.target + 2.0, r.target, reaction_only=True)
    assert only.total.item() == pytest.approx(4.0) and only.recon.item() == 0.0


def test_training_sample_determinism() -> None:
    c, w, _ = _data(4)
    a = semi_noise_training_sample(c, w, generator=torch.Generator().manual_seed(5))
    b = semi_noise_training_sample(c, w, generator=torch.Generator().manual_seed(5))
    d = semi_noise_training_sample(c, w, generator=torch.Generator().manual_seed(6))
    assert torch.equal(a.x, b.x) and torch.equal(a.t, b.t)
    assert not torch.equal(a.x, d.x)
    ctx_x, react_x = split_halves(a.x)
    tt = a.t[:, None, None]
    torch.testing.assert_close(react_x, tt * w + (1 - tt) * c)
    eps = (ctx_x - tt * c) / (1 - tt)  # the context half hides a standard normal
    assert abs(eps.std().item() - 1.0) < 0.05
    with pytest.raises(ValueError):
        semi_noise_training_sample(c, w[:, :8])


def _constant_oracle(
    c: torch.Tensor, w: torch.Tensor, eps: torch.Tensor, reaction_only: bool
) -> Any:
    target = w - c if reaction_only else torch.cat([c - eps, w - c], -1)

    def v(x: torch.Tensor, t: torch.Tensor, **_: Any) -> torch.Tensor:
        return target.to(x.dtype)

    return v


def _state_oracle(c: torch.Tensor, w: torch.Tensor) -> Any:
    """Velocity pointing from the current state to the known end point, (x1 - x)/(1 - t).

    Depends on the state (unlike the constant oracle), yet keeps the straight path.
    """
    end = torch.cat([c, w], -1)

    def v(x: torch.Tensor, t: torch.Tensor, **_: Any) -> torch.Tensor:
        return (end - x) / (1 - t)[:, None, None]

    return v


@pytest.mark.parametrize("reaction_only", [False, True])
@pytest.mark.parametrize("steps", [1, 10])
def test_sampler_recovers_reaction_with_oracle(reaction_only: bool, steps: int) -> None:
    c, w, eps = _data(7, F64)
    out = sample_semi_noise(
        _constant_oracle(c, w, eps, reaction_only),
        c,
        steps=steps,
        noise=eps,
        reaction_only=reaction_only,
    )
    assert out.x.shape == (B, P, R) and out.nfe == steps
    torch.testing.assert_close(out.x, w, atol=1e-12, rtol=0)


def test_sampler_state_dependent_oracle_euler() -> None:
    c, w, eps = _data(8, F64)
    out = sample_semi_noise(_state_oracle(c, w), c, steps=10, noise=eps)
    assert out.nfe == 10
    torch.testing.assert_close(out.x, w, atol=1e-12, rtol=0)


def test_sampler_default_steps_and_determinism() -> None:
    c, _, _ = _data(9)
    seen: list[torch.Tensor] = []

    def v(x: torch.Tensor, t: torch.Tensor, *, text: torch.Tensor) -> torch.Tensor:
        seen.append(t)
        assert x.shape == (B, P, 2 * R)
        return -x.roll(R, dims=-1) * text  # couples the halves: noise reaches the reaction

    cond = {"text": torch.tensor(0.5)}
    a = sample_semi_noise(v, c, generator=torch.Generator().manual_seed(1), cond=cond)
    b = sample_semi_noise(v, c, generator=torch.Generator().manual_seed(1), cond=cond)
    d = sample_semi_noise(v, c, generator=torch.Generator().manual_seed(2), cond=cond)
    assert a.nfe == 10 == len(seen) // 3
    assert torch.equal(a.x, b.x) and not torch.equal(a.x, d.x)
    h = sample_semi_noise(v, c, method="heun", steps=10, cond=cond)
    assert h.nfe == 20


def test_reaction_noise_starts_the_reaction_half_near_the_context() -> None:
    """sigma > 0: the reaction half runs from C + sigma*eps' (mean C, spread sigma) to W;
    the context half is unchanged; sigma 0 is the authors' path exactly."""
    c, w, _ = _data(10, F64)
    big_c, big_w = c.repeat(500, 1, 1), w.repeat(500, 1, 1)  # 2,000 draws per element
    g = torch.Generator().manual_seed(0)
    s = semi_noise_training_sample(big_c, big_w, generator=g, reaction_noise=0.5)
    ctx_x, react_x = split_halves(s.x)
    ctx_v, react_v = split_halves(s.target)
    t = s.t[:, None, None]
    start = (react_x - t * big_w) / (1 - t)  # the path's start, from x_t = t*W + (1-t)*start
    torch.testing.assert_close(react_v, big_w - start, atol=1e-3, rtol=0)
    noise = start - big_c
    assert abs(float(noise.mean())) < 0.01 and abs(float(noise.std()) - 0.5) < 0.01
    eps = (ctx_x - t * big_c) / (1 - t)  # the context half: eps -> C as before
    torch.testing.assert_close(ctx_v, big_c - eps, atol=1e-3, rtol=0)
    assert abs(float((eps * noise).mean())) < 0.01  # eps and eps' independent
    g0, g1 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    plain = semi_noise_training_sample(c, w, generator=g0)
    zero = semi_noise_training_sample(c, w, generator=g1, reaction_noise=0.0)
    assert torch.equal(plain.x, zero.x) and torch.equal(plain.target, zero.target)
    x0 = semi_noise_initial_state(c, generator=torch.Generator().manual_seed(4),
                                  reaction_noise=0.5)  # fmt: skip
    ref = semi_noise_initial_state(c, generator=torch.Generator().manual_seed(4))
    assert torch.equal(split_halves(x0)[0], split_halves(ref)[0])  # same eps first
    assert not torch.equal(split_halves(x0)[1], c)
    assert torch.equal(semi_noise_initial_state(c, generator=g, reaction_only=True), c)
    oracle = sample_semi_noise(_state_oracle(c, w), c, steps=10, reaction_noise=0.5,
                               generator=torch.Generator().manual_seed(5))  # fmt: skip
    torch.testing.assert_close(oracle.x, w, atol=1e-5, rtol=0)  # still ends at W


# ------------------------------------------------------------ draws, dtypes, loss terms
F64 = torch.float64


def _twin(seed: int) -> tuple[torch.Generator, torch.Generator]:
    return torch.Generator().manual_seed(seed), torch.Generator().manual_seed(seed)


@pytest.mark.parametrize("reaction_only", [False, True])
def test_training_sample_draws_t_then_eps_then_eps_prime_in_the_contexts_dtype(reaction_only):
    """The documented order of draws from one generator (t, eps, eps'), the reaction half
    from C + sigma * eps', float64 in and out, the time distribution's own defaults."""
    from umf.flows.paths import sample_time

    context = torch.randn(3, 4, 5, dtype=F64)
    reaction = torch.randn(3, 4, 5, dtype=F64)
    mine, twin = _twin(7)
    got = semi_noise_training_sample(context, reaction, reaction_only=reaction_only,
                                     generator=mine, time_distribution="logit_normal",
                                     reaction_noise=0.3)  # fmt: skip
    t = sample_time(3, distribution="logit_normal", loc=0.0, scale=1.0, generator=twin, dtype=F64)
    eps = torch.randn(context.shape, generator=twin, dtype=F64)
    start = context + 0.3 * torch.randn(context.shape, generator=twin, dtype=F64)
    want = semi_noise_state(context, reaction, eps, t, reaction_only=reaction_only,
                            reaction_start=start)  # fmt: skip
    assert got.x.dtype == got.t.dtype == got.target.dtype == F64
    for a, b in ((got.x, want.x), (got.t, want.t), (got.target, want.target)):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_initial_state_and_one_step_start_at_noise_and_c_plus_sigma_eps_prime():
    context = torch.randn(2, 4, 6, dtype=F64)
    mine, twin = _twin(11)
    x0 = semi_noise_initial_state(context, generator=mine, reaction_noise=0.2)
    eps = torch.randn(context.shape, generator=twin, dtype=F64)
    start = context + 0.2 * torch.randn(context.shape, generator=twin, dtype=F64)
    assert x0.dtype == F64
    torch.testing.assert_close(x0, torch.cat([eps, start], dim=-1), atol=0, rtol=0)
    given = torch.randn(context.shape, dtype=F64)  # a noise passed in is used as is

    def still(x, t):
        return torch.zeros_like(x)

    mine, twin = _twin(5)
    out = sample_semi_noise(still, context, steps=1, noise=given, generator=mine,
                            reaction_noise=0.5)  # fmt: skip
    eps_prime = torch.randn(context.shape, generator=twin, dtype=F64)  # no eps drawn: given
    torch.testing.assert_close(out.x, context + 0.5 * eps_prime, atol=0, rtol=0)


def test_loss_weighs_reconstruction_by_lambda_and_honours_the_mask():
    pred, target = torch.randn(2, 4, 6), torch.randn(2, 4, 6)
    mask = torch.tensor([[True, True, False, False], [True, True, True, False]])
    wild = pred.clone()
    wild[~mask] = 1e6  # what padded tokens hold must not count
    plain = semi_noise_loss(pred, target, mask=mask)
    torch.testing.assert_close(plain.total, plain.reaction + plain.recon)  # lambda 1 default
    assert semi_noise_loss(wild, target, mask=mask).total == plain.total
    half = semi_noise_loss(pred, target, lambda_recon=0.5, mask=mask)
    torch.testing.assert_close(half.total, plain.reaction + 0.5 * plain.recon)
    only = semi_noise_loss(wild[..., :3], target[..., :3], reaction_only=True, mask=mask)
    assert only.reaction == only.total < 1e3 and only.recon == 0


def test_training_sample_passes_its_time_location_and_scale_on():
    """logit-normal t = sigmoid(loc + scale * z) with the caller's loc and scale."""
    context = torch.randn(5, 4, 3, dtype=F64)
    reaction = torch.randn(5, 4, 3, dtype=F64)
    mine, twin = _twin(13)
    got = semi_noise_training_sample(context, reaction, generator=mine,
                                     time_distribution="logit_normal", time_loc=0.7,
                                     time_scale=2.5)  # fmt: skip
    t = torch.sigmoid(0.7 + 2.5 * torch.randn(5, generator=twin, dtype=F64))
    torch.testing.assert_close(got.t, t, atol=0, rtol=0)
    eps = torch.randn(context.shape, generator=twin, dtype=F64)
    want = semi_noise_state(context, reaction, eps, t)
    torch.testing.assert_close(got.x, want.x, atol=0, rtol=0)


def test_shape_messages():
    c = torch.zeros(2, 4, 6)
    with pytest.raises(ValueError, match=r"^context \(2, 4, 6\) vs reaction \(2, 4, 5\)$"):
        semi_noise_training_sample(c, c[..., :5])
    with pytest.raises(ValueError, match=r"^joint state needs an even channel count, got 5$"):
        split_halves(c[..., :5])


@pytest.mark.parametrize("reaction_only", [False, True])
def test_warm_state_is_the_training_state_towards_the_proposal(reaction_only: bool) -> None:
    """At t the warm state is what training puts there had the reaction been the proposal:
    t*C + (1-t)*eps || t*P + (1-t)*(C + sigma eps')."""
    c, p, eps = _data(10, F64)
    start = c + 0.125 * torch.randn(c.shape, generator=torch.Generator().manual_seed(3), dtype=F64)
    x0 = start if reaction_only else torch.cat([eps, start], -1)
    for t in (0.25, 0.5, 0.9):
        got = warm_state(x0, c, p, t, reaction_only=reaction_only)
        want = semi_noise_state(c, p, eps, torch.full((B,), t, dtype=F64),
                                reaction_only=reaction_only, reaction_start=start).x  # fmt: skip
        torch.testing.assert_close(got, want, atol=1e-12, rtol=0)
    for t in (0.0, 1.0, -0.5):
        with pytest.raises(ValueError, match="0 < t < 1"):
            warm_state(x0, c, p, t)


def test_warm_sampler_starts_at_t0_with_the_remaining_steps() -> None:
    """A still field leaves the warm state as it is; a field pointing at [C || W] reaches W
    from it; the steps are the remaining share, evaluated from t0 on."""
    c, p, eps = _data(11, F64)
    times: list[float] = []

    def still(x: torch.Tensor, t: torch.Tensor, **_: Any) -> torch.Tensor:
        times.append(float(t[0]))
        return torch.zeros_like(x)

    out = sample_semi_noise(still, c, steps=4, noise=eps, warm=p, warm_t=0.5)
    assert out.nfe == 2 and times == [0.5, 0.75]
    torch.testing.assert_close(out.x, 0.5 * p + 0.5 * c, atol=1e-12, rtol=0)
    _, w, _ = _data(12, F64)
    out = sample_semi_noise(_state_oracle(c, w), c, steps=10, noise=eps, warm=p, warm_t=0.3)
    assert out.nfe == 7
    torch.testing.assert_close(out.x, w, atol=1e-12, rtol=0)
    cold = sample_semi_noise(still, c, steps=4, noise=eps, warm=p, warm_t=0.0)
    assert cold.nfe == 4 and torch.equal(cold.x, c)  # 0: the usual start
    one = sample_semi_noise(still, c, steps=1, noise=eps, warm=p, warm_t=0.9)
    assert one.nfe == 1  # at least one step
