"""P-Flow module: loss wiring, corpus weighting, CFG dropout, sampler, and a toy fit."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from test_denoiser import D_TEXT, make_text, tiny_denoiser
from umf.config import PFlowConfig
from umf.flows import EVALS_PER_STEP
from umf.models.denoiser import FROM_CONFIG
from umf.models.pflow import PFlow, _stage_field, resolve_steps, stage_scales
from umf.text import TextFeatures

P, R = 16, 8


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


def pflow(**kw: Any) -> PFlow:
    torch.manual_seed(0)
    cfg = PFlowConfig(denoiser=tiny_denoiser(), **{"steps": (3, 2), **kw})
    return PFlow(cfg, P, R, D_TEXT)


def batch(
    b: int = 6, seed: int = 0
) -> tuple[torch.Tensor, TextFeatures, TextFeatures, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    z1 = torch.randn(b, P, R, generator=g)
    ds = torch.tensor([0, 1] * (b // 2))
    return z1, make_text(b, seed=seed), make_text(1, length=3, seed=99), ds


@pytest.mark.parametrize(("layout", "k"), [("1d", 2), ("2d", 2), ("1d", 1), ("1d", 3)])
def test_loss_backward_reaches_every_parameter(layout: str, k: int) -> None:
    model = pflow(layout=layout, num_stages=k, steps=(2,) * k)
    if k == 1:  # the no-pyramid ablation is plain flow matching over [0, 1]
        assert model.net.stage_emb is None
        assert [(w.start, w.end) for w in model.pyramid.windows] == [(0.0, 1.0)]
    z1, text, empty, ds = batch()
    for dataset in (ds, torch.zeros_like(ds)):  # mixed batch, then one corpus only
        model.zero_grad(set_to_none=True)
        out = model(z1, text, empty, dataset, generator=torch.Generator().manual_seed(1))
        assert torch.isfinite(out["total"]) and out["total"].requires_grad
        assert all(not v.requires_grad for key, v in out.items() if key != "total")
        assert {f"stage{s}" for s in range(1, k + 1)} >= {key for key in out if "stage" in key}
        out["total"].backward()
        missing = [n for n, p in model.named_parameters() if p.grad is None]
        assert not missing, missing


def test_single_person_weight_scales_dataset_zero_samples() -> None:
    z1, text, empty, ds = batch()
    totals = {}
    for w in (0.0, 1.0, 0.1):
        model = pflow(single_person_weight=w)  # same seed: same weights
        out = model.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(3))
        totals[w] = float(out["total"].detach())
        if w == 1.0:
            assert totals[w] == pytest.approx(float(out["mse"]), rel=1e-5)
    # total is linear in the weight: t(w) = t(0) + w * (t(1) - t(0))
    assert totals[0.1] == pytest.approx(totals[0.0] + 0.1 * (totals[1.0] - totals[0.0]), rel=1e-5)
    assert totals[0.0] < totals[1.0]


def test_p_uncond_one_trains_on_the_empty_prompt_only() -> None:
    z1, text, empty, ds = batch()
    model = pflow(p_uncond=1.0)
    a = model.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(4))
    b = model.loss(z1, make_text(6, seed=5), empty, ds, generator=torch.Generator().manual_seed(4))
    assert float(a["total"].detach()) == pytest.approx(float(b["total"].detach()), rel=1e-6)
    model = pflow(p_uncond=0.0)
    c = model.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(4))
    d = model.loss(z1, make_text(6, seed=5), empty, ds, generator=torch.Generator().manual_seed(4))
    assert float(c["total"].detach()) != pytest.approx(float(d["total"].detach()), rel=1e-6)


def count_forwards(model: PFlow) -> list[int]:
    """Wrap the network's forward; returns the list of batch sizes it is called with."""
    calls: list[int] = []
    forward = model.net.forward

    def counted(x: torch.Tensor, *args: Any, **kw: Any) -> torch.Tensor:
        calls.append(x.shape[0])
        return forward(x, *args, **kw)

    model.net.forward = counted  # type: ignore[method-assign]
    return calls


@pytest.mark.parametrize(("layout", "k"), [("1d", 2), ("2d", 2), ("1d", 1)])
@pytest.mark.parametrize("solver", ["euler", "heun"])
def test_sample_shape_nfe_and_determinism(layout: str, k: int, solver: str) -> None:
    model = pflow(layout=layout, num_stages=k)
    text, empty = make_text(2, seed=1), make_text(1, length=2, seed=2)
    calls = count_forwards(model)
    z, nfe = model.sample(
        text, empty, num_samples=3, solver=solver, generator=torch.Generator().manual_seed(0)
    )  # type: ignore[arg-type]
    assert z.shape == (6, P, R) and torch.isfinite(z).all()
    total_steps = sum(resolve_steps(model.cfg.steps, k))
    assert nfe == total_steps * EVALS_PER_STEP[solver]
    assert calls == [12] * nfe  # CFG: one double-batch forward per guided evaluation
    again, _ = model.sample(
        text, empty, num_samples=3, solver=solver, generator=torch.Generator().manual_seed(0)
    )  # type: ignore[arg-type]
    assert torch.equal(z, again)
    other, _ = model.sample(
        text, empty, num_samples=3, solver=solver, generator=torch.Generator().manual_seed(1)
    )  # type: ignore[arg-type]
    assert not torch.allclose(z, other)


def test_sample_without_guidance_and_mode_restored() -> None:
    model = pflow().train()
    calls = count_forwards(model)
    text = make_text(3)
    z, nfe = model.sample(text, guidance=None, steps=(4, 2))
    assert z.shape == (3, P, R) and nfe == 6 and calls == [3] * 6
    assert model.training  # sample() used eval mode only for the duration
    _, nfe = model.sample(text, make_text(1), guidance=1.0, steps=5)
    assert nfe == 5
    with pytest.raises(ValueError, match="uncond"):
        model.sample(text, guidance=2.0)


def test_stage_scales_guide_the_finest_stage_on_its_own() -> None:
    assert stage_scales(PFlowConfig(guidance=2.0, num_stages=3)) == (2.0, 2.0, 2.0)
    assert stage_scales(PFlowConfig(guidance=3.0, fine_guidance=0.0)) == (3.0, 0.0)
    assert stage_scales(PFlowConfig(guidance=3.0, fine_guidance=1.0, num_stages=3)) == (
        3.0, 3.0, None)  # fmt: skip
    assert stage_scales(PFlowConfig(guidance=1.0, fine_guidance=4.0)) == (None, 4.0)
    # a scale the caller gives is every stage's (as `--guidance` promises)
    assert stage_scales(PFlowConfig(guidance=3.0, fine_guidance=0.0), 2.0) == (2.0, 2.0)
    assert stage_scales(PFlowConfig(guidance=3.0, fine_guidance=0.0), None) == (None, None)
    assert stage_scales(PFlowConfig(fine_guidance=0.0, num_stages=1)) == (0.0,)
    with pytest.raises(ValueError, match="fine_guidance"):
        stage_scales(PFlowConfig(fine_guidance=-1.0), FROM_CONFIG)


def test_stage_field_guides_each_stage_with_its_own_scale() -> None:
    """v_u + s (v_c - v_u) per stage: the coarse stage (2) at scale 3, the fine (1) at 0."""

    def net(x: torch.Tensor, t: torch.Tensor, *, stage: torch.Tensor, text: torch.Tensor):
        return x * 0 + text[:, None, None] + 10 * stage[:, None, None]

    cond, uncond = {"text": torch.tensor([1.0, 1.0])}, {"text": torch.tensor([0.0, 0.0])}
    field = _stage_field(net, (3.0, 0.0), cond, uncond)
    x, t = torch.zeros(2, P, R), torch.zeros(2)
    coarse = field(x, t, stage=torch.full((2,), 2))
    fine = field(x, t, stage=torch.full((2,), 1))
    assert torch.allclose(coarse, torch.full_like(x, 20 + 3.0))  # 20 + 0 + 3 * (1 - 0)
    assert torch.allclose(fine, torch.full_like(x, 10 + 0.0))  # unconditional
    plain = _stage_field(net, (None, None), cond, uncond)
    assert torch.allclose(plain(x, t, stage=torch.full((2,), 1)), torch.full_like(x, 11.0))


def test_fine_guidance_unset_or_equal_samples_as_before() -> None:
    """Unset, or equal to ``guidance``, it samples exactly as before; otherwise it changes
    the samples at the same number of evaluations."""
    text, empty = make_text(3), make_text(1)
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    base, _ = pflow(guidance=2.5).sample(text, empty, generator=gen())
    same, _ = pflow(guidance=2.5, fine_guidance=2.5).sample(text, empty, generator=gen())
    assert torch.equal(base, same)
    other, nfe = pflow(guidance=2.5, fine_guidance=0.0).sample(text, empty, generator=gen())
    assert nfe == 5 and not torch.allclose(base, other)
    # the caller's scale overrides both stages
    c, _ = pflow(guidance=2.5, fine_guidance=0.0).sample(text, empty, guidance=2.5,
                                                         generator=gen())  # fmt: skip
    assert torch.equal(c, base)


def test_stage_starts_come_from_the_config() -> None:
    uniform = pflow().pyramid.windows
    assert [(w.stage, w.start) for w in uniform] == [(2, 0.0), (1, 0.5)]
    early = pflow(starts=(0.0, 0.25)).pyramid.windows
    assert [(w.stage, w.start) for w in early] == [(2, 0.0), (1, 0.25)]
    assert early[0].end < uniform[0].end  # the coarse stage hands over sooner
    with pytest.raises(ValueError, match="starts"):
        pflow(starts=(0.1, 0.5))


def test_resolve_steps() -> None:
    assert resolve_steps((45, 5), 2) == (45, 5)
    assert resolve_steps((45, 5), 1) == (50,)
    assert resolve_steps(50, 2) == (45, 5)
    assert resolve_steps(9, 3) == (3, 3, 3)
    with pytest.raises(ValueError):
        resolve_steps((1, 2), 3)


@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_toy_text_classes_are_learned(layout: str) -> None:
    """Two 'prompts', each with its own fixed latent pattern: after 200 steps the samples
    of each prompt sit clearly closer to their own pattern (train + pyramid sampler fit)."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    patterns = torch.randn(2, P, R, generator=g)
    texts = make_text(2, length=4, seed=7)
    empty = make_text(1, length=2, seed=8)
    cfg = PFlowConfig(denoiser=tiny_denoiser(num_layers=2), layout=layout, steps=(6, 4))
    model = PFlow(cfg, P, R, D_TEXT)
    opt = torch.optim.AdamW(model.parameters(), lr=5e-3)
    b = 16
    for _ in range(200):
        cls = torch.randint(0, 2, (b,), generator=g)
        z1 = patterns[cls] + 0.1 * torch.randn(b, P, R, generator=g)
        text = TextFeatures(texts.tokens[cls], texts.mask[cls], texts.pooled[cls])
        ds = torch.randint(0, 2, (b,), generator=g)
        loss = model.loss(z1, text, empty, ds, generator=g)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    # guidance 1: CFG would extrapolate past the class means on purpose
    z, _ = model.sample(texts, empty, num_samples=16, guidance=1.0, generator=g)
    for c in range(2):
        mean = z[c * 16 : (c + 1) * 16].mean(0)
        right = (mean - patterns[c]).norm()
        wrong = (mean - patterns[1 - c]).norm()
        assert right < 0.5 * wrong, (c, float(right), float(wrong))
