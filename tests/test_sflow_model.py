"""Context adapter and S-Flow module: masking, order invariance, loss variants, one-pass
sampling, the shared-backbone ablation and a toy reaction rule."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from test_denoiser import D_TEXT, make_text, tiny_denoiser
from umf.config import PFlowConfig, SFlowConfig
from umf.flows import EVALS_PER_STEP, semi_noise_loss, semi_noise_training_sample
from umf.models.context import ContextAdapter, masked_person_mean
from umf.models.pflow import PFlow
from umf.models.sflow import SFlow
from umf.text import TextFeatures

P, R = 16, 8
ATOL = 1e-5


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


def adapter(**kw: Any) -> ContextAdapter:
    torch.manual_seed(0)
    args: dict[str, Any] = {"num_tokens": P, "dropout": 0.0, **kw}
    return ContextAdapter(R, 2, 32, 2, **args).eval()


def people(b: int, n: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(b, n, P, R, generator=torch.Generator().manual_seed(seed))


MASK = torch.tensor([[1, 0, 1, 1], [1, 1, 0, 0], [0, 0, 1, 0]], dtype=torch.bool)


# ------------------------------------------------------------------ context adapter
@pytest.mark.parametrize("positional", [False, True])
def test_adapter_is_invariant_to_the_order_of_people(positional: bool) -> None:
    net = adapter(positional=positional)
    prev = people(3, 4)
    out = net(prev, MASK)
    assert out.shape == (3, P, R)
    for perm in ([3, 2, 1, 0], [1, 3, 0, 2]):
        torch.testing.assert_close(net(prev[:, perm], MASK[:, perm]), out, atol=ATOL, rtol=0)


def test_adapter_ignores_absent_people_exactly() -> None:
    net = adapter()
    prev = people(3, 4)
    out = net(prev, MASK)
    junk = torch.where(MASK[..., None, None], prev, torch.full_like(prev, float("nan")))
    assert torch.equal(net(junk, MASK), out)  # bit for bit, NaN never leaks
    for i in range(3):  # same as a batch holding only the present people
        alone = net(prev[i : i + 1, MASK[i]], torch.ones(1, int(MASK[i].sum()), dtype=torch.bool))
        torch.testing.assert_close(alone[0], out[i], atol=ATOL, rtol=0)
    with pytest.raises(ValueError, match="at least one"):
        net(prev, torch.zeros(3, 4, dtype=torch.bool))


@pytest.mark.parametrize("n_prev", [1, 5])
def test_adapter_any_number_of_people(n_prev: int) -> None:
    net = adapter()
    out = net(people(2, n_prev), torch.ones(2, n_prev, dtype=torch.bool))
    assert out.shape == (2, P, R) and torch.isfinite(out).all()


def test_disabled_adapter_is_the_masked_mean() -> None:
    net = adapter(enabled=False)
    assert not list(net.parameters())
    prev = people(3, 4)
    expect = torch.stack([prev[i, MASK[i]].mean(0) for i in range(3)])
    torch.testing.assert_close(net(prev, MASK), expect)
    torch.testing.assert_close(masked_person_mean(prev, MASK), expect)


def test_adapter_starts_near_the_mean_and_learns_a_residual() -> None:
    """No final norm: the residual stream keeps the latents' scale."""
    prev = people(3, 4)
    out = adapter()(prev, MASK)
    mean = masked_person_mean(prev, MASK)
    assert (out - mean).abs().mean() < mean.abs().mean()


# ------------------------------------------------------------------ S-Flow
def sflow(backbone: Any = None, **kw: Any) -> SFlow:
    torch.manual_seed(0)
    args: dict[str, Any] = {"context_heads": 2, "context_ff_dim": 32, "steps": 4, **kw}
    cfg = SFlowConfig(denoiser=tiny_denoiser(), **args)
    return SFlow(cfg, P, R, D_TEXT, backbone=backbone)


def sbatch(b: int = 3) -> tuple[torch.Tensor, ...]:
    return people(b, 4, seed=1), MASK[:b], people(b, 1, seed=2)[:, 0]


VARIANTS = [
    {},
    {"reaction_only": True},
    {"lambda_recon": 0.0},
    {"context_adapter": False},
    {"context_positional": True, "context_noise": 0.1},
    {"context_condition": True, "reaction_noise": 0.5},
]


@pytest.mark.parametrize("kw", VARIANTS)
def test_loss_backward_reaches_every_parameter(kw: dict[str, Any]) -> None:
    model = sflow(**kw).train()
    prev, mask, w = sbatch()
    out = model(prev, mask, w, make_text(3), make_text(1, length=2, seed=5))
    assert torch.isfinite(out["total"])
    out["total"].backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None]
    assert not missing, missing
    if kw.get("context_adapter", True):
        assert any(p.grad.abs().max() > 0 for p in model.context.parameters())  # type: ignore[union-attr]


def test_loss_variants() -> None:
    prev, mask, w = sbatch()
    text, empty = make_text(3), make_text(1, length=2, seed=5)

    def loss(**kw: Any) -> dict[str, float]:
        model = sflow(**kw).eval()
        with torch.no_grad():
            out = model.loss(prev, mask, w, text, empty, generator=torch.Generator().manual_seed(0))
        return {k: float(v) for k, v in out.items()}

    full, two, none = loss(), loss(lambda_recon=2.0), loss(lambda_recon=0.0)
    assert full["recon"] > 0 and full["total"] == pytest.approx(full["reaction"] + full["recon"])
    assert two["total"] == pytest.approx(two["reaction"] + 2 * two["recon"])
    assert none["total"] == pytest.approx(none["reaction"]) and none["recon"] > 0
    only = loss(reaction_only=True)
    assert only["recon"] == 0.0 and only["total"] == only["reaction"]
    assert sflow(reaction_only=True).net.in_dim == R and sflow().net.in_dim == 2 * R


def test_loss_trains_on_the_real_previous_latents() -> None:
    """The state and targets are built from C = adapter(real latents) (SPEC 7 (a))."""
    model = sflow(p_uncond=0.0).eval()
    prev, mask, w = sbatch()
    text, empty = make_text(3), make_text(1, length=2, seed=5)
    with torch.no_grad():
        out = model.loss(prev, mask, w, text, empty, generator=torch.Generator().manual_seed(0))
        g = torch.Generator().manual_seed(0)
        s = semi_noise_training_sample(model.context(prev, mask), w, generator=g)
        expect = semi_noise_loss(model.velocity(s.x, s.t, text), s.target)
    assert float(out["total"]) == pytest.approx(float(expect.total), rel=1e-6)


def test_context_noise_is_relative_to_the_latent_spread() -> None:
    model = sflow(context_noise=0.5)
    scale = torch.linspace(0.1, 3.0, R)
    prev = people(256, 2, seed=3) * scale
    mask = torch.ones(256, 2, dtype=torch.bool)
    mask[::2, 1] = False
    noisy = model.perturb_context(prev, mask, torch.Generator().manual_seed(0))
    rel = ((noisy - prev) / (0.5 * scale))[mask]
    assert abs(float(rel.std()) - 1.0) < 0.05
    assert torch.equal(sflow().perturb_context(prev, mask), prev)  # context_noise = 0


def count_forwards(module: torch.nn.Module) -> list[int]:
    calls: list[int] = []
    forward = module.forward

    def counted(x: torch.Tensor, *args: Any, **kw: Any) -> torch.Tensor:
        calls.append(x.shape[0])
        return forward(x, *args, **kw)

    module.forward = counted  # type: ignore[method-assign]
    return calls


@pytest.mark.parametrize("solver", ["euler", "rk4"])
@pytest.mark.parametrize("reaction_only", [False, True])
def test_sample_runs_the_ode_once(solver: str, reaction_only: bool) -> None:
    model = sflow(reaction_only=reaction_only)
    prev, mask, _ = sbatch()
    text, empty = make_text(3), make_text(1, length=2, seed=5)
    calls = count_forwards(model.net)
    w, nfe = model.sample(
        prev, mask, text, empty, solver=solver, generator=torch.Generator().manual_seed(0)
    )  # type: ignore[arg-type]
    assert w.shape == (3, P, R) and torch.isfinite(w).all()
    assert nfe == model.cfg.steps * EVALS_PER_STEP[solver]
    assert calls == [6] * nfe  # guided: one double-batch forward per evaluation
    again, _ = model.sample(
        prev, mask, text, empty, solver=solver, generator=torch.Generator().manual_seed(0)
    )  # type: ignore[arg-type]
    assert torch.equal(w, again)
    calls.clear()
    _, nfe = model.sample(prev, mask, text, guidance=None, steps=7)
    assert nfe == 7 * EVALS_PER_STEP["euler"] and calls == [3] * nfe


def test_shared_backbone_ablation() -> None:
    torch.manual_seed(0)
    pf = PFlow(PFlowConfig(denoiser=tiny_denoiser()), P, R, D_TEXT)
    model = sflow(backbone=pf.net, shared_backbone=True)
    assert model.net is pf.net and model.in_adapter is not None
    assert model.in_adapter.in_features == 2 * R and model.out_adapter.out_features == 2 * R  # type: ignore[union-attr]
    prev, mask, w = sbatch()
    out = model.loss(prev, mask, w, make_text(3), make_text(1))
    out["total"].backward()
    assert not [n for n, p in model.named_parameters() if p.grad is None]
    z, nfe = model.sample(prev, mask, make_text(3), make_text(1), steps=3)
    assert z.shape == (3, P, R) and nfe == 3
    with pytest.raises(ValueError, match="shared_backbone"):
        sflow(backbone=pf.net)
    with pytest.raises(ValueError, match="shared_backbone"):
        sflow(shared_backbone=True)


def test_toy_reaction_rule_is_learned() -> None:
    """w = C + offset(text), C the mean of 1-2 previous people: after 200 steps the samples
    beat both shortcuts (ignoring the text, ignoring the context) by far."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    offsets = 2.0 * torch.randn(2, 1, R, generator=g)
    texts = make_text(2, length=4, seed=7)
    empty = make_text(1, length=2, seed=8)
    cfg = SFlowConfig(
        denoiser=tiny_denoiser(num_layers=2),
        context_heads=2,
        context_ff_dim=32,
        context_layers=1,
        steps=8,
    )
    model = SFlow(cfg, P, R, D_TEXT)
    opt = torch.optim.AdamW(model.parameters(), lr=5e-3)

    def draw(b: int) -> tuple[torch.Tensor, ...]:
        cls = torch.randint(0, 2, (b,), generator=g)
        prev = torch.randn(b, 2, P, R, generator=g)
        mask = torch.ones(b, 2, dtype=torch.bool)
        mask[:, 1] = torch.rand(b, generator=g) < 0.5
        context = masked_person_mean(prev, mask)
        return cls, prev, mask, context, context + offsets[cls]

    for _ in range(200):
        cls, prev, mask, _, w = draw(16)
        text = TextFeatures(texts.tokens[cls], texts.mask[cls], texts.pooled[cls])
        loss = model.loss(prev, mask, w, text, empty, generator=g)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    cls, prev, mask, context, w = draw(64)
    text = TextFeatures(texts.tokens[cls], texts.mask[cls], texts.pooled[cls])
    pred, _ = model.sample(prev, mask, text, empty, guidance=1.0, generator=g)
    err = (pred - w).square().mean()
    no_text = (context - w).square().mean()
    no_context = (offsets[cls] - w).square().mean()
    assert err < 0.2 * min(no_text, no_context), (float(err), float(no_text), float(no_context))


def test_sampling_starts_the_reaction_at_the_context_plus_reaction_noise(monkeypatch) -> None:
    """With the field held at zero the sampler returns its start: the context exactly for
    reaction_noise 0 (the authors' path) and the context plus noise of std sigma in the
    model's normalised latent space otherwise. A sampler that ignored the configured
    reaction_noise would return the context for both."""
    prev, mask, _ = sbatch()
    text = make_text(3)
    starts = {}
    for sigma in (0.0, 0.5):
        model = sflow(reaction_noise=sigma)
        monkeypatch.setattr(model, "velocity", lambda x, t, **kw: torch.zeros_like(x))
        w, _ = model.sample(prev, mask, text, guidance=None,
                            generator=torch.Generator().manual_seed(0))  # fmt: skip
        with torch.no_grad():
            context = model.context(model.latent_norm.normalize(prev), mask)
        starts[sigma] = model.latent_norm.normalize(w) - context
    torch.testing.assert_close(starts[0.0], torch.zeros_like(starts[0.0]), atol=1e-5, rtol=0)
    spread = float(starts[0.5].std())
    assert 0.4 < spread < 0.6, spread  # 3 x 16 x 8 draws of N(0, 0.5^2)


def test_the_context_beside_the_state_starts_as_the_model_without_it() -> None:
    """``context_condition`` adds C to each latent token through a zero-initialised
    projection: with a plain model's weights it computes exactly what that model does,
    guided and unguided; once the projection moves, the context changes the velocity."""
    plain, model = sflow().eval(), sflow(context_condition=True).eval()
    missing, unexpected = model.load_state_dict(plain.state_dict(), strict=False)
    assert sorted(missing) == ["net.cond_proj.bias", "net.cond_proj.weight"] and not unexpected
    prev, mask, _ = sbatch()
    text, empty = make_text(3), make_text(1, length=2, seed=5)
    x, t = torch.randn(3, P, 2 * R), torch.rand(3)
    c = plain.context(prev, mask)
    with torch.no_grad():
        assert torch.equal(model.velocity(x, t, text, c), plain.velocity(x, t, text))
        for guidance in (None, 2.0):
            a, _ = plain.sample(prev, mask, text, empty, guidance=guidance,
                                generator=torch.Generator().manual_seed(0))  # fmt: skip
            b, _ = model.sample(prev, mask, text, empty, guidance=guidance,
                                generator=torch.Generator().manual_seed(0))  # fmt: skip
            torch.testing.assert_close(a, b, atol=1e-6, rtol=0)
        torch.nn.init.normal_(model.net.cond_proj.weight, std=0.5)
        moved = model.velocity(x, t, text, c)
        assert not torch.allclose(moved, plain.velocity(x, t, text))
        assert not torch.allclose(model.velocity(x, t, text, c + 1.0), moved)
    with pytest.raises(ValueError, match="pass context"):
        model.velocity(x, t, text)
    torch.manual_seed(0)
    pf = PFlow(PFlowConfig(denoiser=tiny_denoiser()), P, R, D_TEXT)
    with pytest.raises(ValueError, match="own transformer"):
        sflow(backbone=pf.net, shared_backbone=True, context_condition=True)


def test_a_noisy_reaction_start_needs_the_context_beside_the_state() -> None:
    """w = C + offset(text) with the reaction half starting at C + eps' (sigma 1): the state
    shows C only through noise, so the plain S-Flow's samples miss C by far more than the one
    that reads C beside the state (same data, steps and seeds)."""

    def trained_error(**kw: Any) -> float:
        torch.manual_seed(0)
        g = torch.Generator().manual_seed(0)
        offsets = 2.0 * torch.randn(2, 1, R, generator=g)
        texts, empty = make_text(2, length=4, seed=7), make_text(1, length=2, seed=8)
        cfg = SFlowConfig(denoiser=tiny_denoiser(num_layers=2), context_heads=2,
                          context_ff_dim=32, context_layers=1, steps=8, reaction_noise=1.0,
                          context_adapter=False, **kw)  # fmt: skip
        model = SFlow(cfg, P, R, D_TEXT)
        opt = torch.optim.AdamW(model.parameters(), lr=5e-3)

        def draw(b: int) -> tuple[torch.Tensor, ...]:
            cls = torch.randint(0, 2, (b,), generator=g)
            prev = torch.randn(b, 1, P, R, generator=g)
            w = prev[:, 0] + offsets[cls]
            return TextFeatures(texts.tokens[cls], texts.mask[cls], texts.pooled[cls]), prev, w

        one = torch.ones(16, 1, dtype=torch.bool)
        for _ in range(200):
            text, prev, w = draw(16)
            loss = model.loss(prev, one, w, text, empty, generator=g)["total"]
            opt.zero_grad()
            loss.backward()
            opt.step()
        text, prev, w = draw(64)
        pred, _ = model.sample(prev, torch.ones(64, 1, dtype=torch.bool), text, empty,
                               guidance=1.0, generator=g)  # fmt: skip
        return float((pred - w).square().mean())

    plain, beside = trained_error(), trained_error(context_condition=True)
    print(f"squared error: plain {plain:.2f}, context beside the state {beside:.2f}")  # docs
    assert beside < 0.5 * plain, (beside, plain)
