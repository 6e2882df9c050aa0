"""Per-person prompts in the flows: a zero-initialised own-prompt projection (a model
fine-tuned with it starts as the model it came from), dropout of the own prompt in
training, guidance over both prompts, and a toy where only the own prompt says what to do."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from test_denoiser import D_TEXT, make_text, tiny_denoiser
from umf.config import PFlowConfig, SFlowConfig
from umf.models.denoiser import expand_text
from umf.models.pflow import PFlow
from umf.models.sflow import SFlow
from umf.text import TextFeatures

P, R = 16, 8

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


def pflow(person: bool, **kw: Any) -> PFlow:
    torch.manual_seed(0)
    cfg = PFlowConfig(denoiser=tiny_denoiser(person_text=person), **{"steps": (3, 2), **kw})
    return PFlow(cfg, P, R, D_TEXT)


def sflow(person: bool, **kw: Any) -> SFlow:
    torch.manual_seed(0)
    kw.setdefault("denoiser", tiny_denoiser(person_text=person))
    cfg = SFlowConfig(steps=3, **kw)
    return SFlow(cfg, P, R, D_TEXT)


def grown(old: torch.nn.Module, new: torch.nn.Module) -> torch.nn.Module:
    """``new`` with ``old``'s weights and its own (zero) person projection: a fine-tune's
    starting point."""
    missing, unexpected = new.load_state_dict(old.state_dict(), strict=False)
    assert not unexpected and missing and all("person_proj" in k for k in missing)
    return new


def randomise_projection(model: torch.nn.Module) -> None:
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "person_proj" in name:
                p.copy_(torch.randn(p.shape, generator=torch.Generator().manual_seed(3)) * 0.3)


def test_a_grown_pflow_computes_what_it_did_before() -> None:
    old, new = pflow(False), grown(pflow(False), pflow(True))
    z1 = torch.randn(4, P, R, generator=torch.Generator().manual_seed(0))
    text, empty, own = make_text(4, seed=1), make_text(1, length=2, seed=2), make_text(4, seed=5)
    ds = torch.tensor([0, 1, 0, 1])
    a = old.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(1))
    b = new.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(1),
                 person_text=own, person_present=torch.ones(4, dtype=torch.bool))  # fmt: skip
    # the own-prompt dropout draws once more, after every draw the old loss makes
    assert float(a["total"].detach()) == pytest.approx(float(b["total"].detach()), rel=1e-6)
    za, _ = old.sample(text, empty, generator=torch.Generator().manual_seed(0))
    zb, _ = new.sample(text, empty, generator=torch.Generator().manual_seed(0), person_text=own)
    assert torch.allclose(za, zb, atol=1e-6)


def test_the_own_prompt_reaches_the_velocity_only_where_present() -> None:
    model = pflow(True)
    randomise_projection(model)
    text, own, other = make_text(3, seed=1), make_text(3, seed=5), make_text(3, seed=6)
    none = model.net.encode_text(text)
    present = torch.tensor([True, False, True])
    with_own = model.net.encode_text(text, own, present)
    with_other = model.net.encode_text(text, other, present)
    assert torch.equal(with_own[1], none[1]) and torch.equal(with_other[1], none[1])
    for i in (0, 2):
        assert not torch.allclose(with_own[i], none[i])
        assert not torch.allclose(with_own[i], with_other[i])
    with pytest.raises(ValueError, match="per-person"):
        pflow(False).net.encode_text(text, own)


def test_gradients_reach_the_projection_and_dropout_silences_it() -> None:
    model = pflow(True, p_uncond=0.0, p_person_drop=0.0)
    z1 = torch.randn(4, P, R, generator=torch.Generator().manual_seed(0))
    text, empty, own = make_text(4, seed=1), make_text(1, length=2, seed=2), make_text(4, seed=5)
    ds = torch.ones(4, dtype=torch.long)
    out = model.loss(z1, text, empty, ds, generator=torch.Generator().manual_seed(1),
                     person_text=own, person_present=torch.ones(4, dtype=torch.bool))  # fmt: skip
    out["total"].backward()
    assert model.net.person_proj.weight.grad.abs().sum() > 0
    randomise_projection(model)

    def total(person_text: TextFeatures, drop: float) -> float:
        model.cfg.p_person_drop = drop
        gen = torch.Generator().manual_seed(1)
        present = torch.ones(4, dtype=torch.bool)
        return float(model.loss(z1, text, empty, ds, generator=gen, person_text=person_text,
                                person_present=present)["total"].detach())  # fmt: skip

    other = make_text(4, seed=9)
    assert total(own, 1.0) == pytest.approx(total(other, 1.0), rel=1e-6)  # always dropped
    assert total(own, 0.0) != pytest.approx(total(other, 0.0), rel=1e-6)  # always kept


def test_sflow_own_prompt_changes_the_reaction_and_guidance_has_neither() -> None:
    old, new = sflow(False), grown(sflow(False), sflow(True))
    prev = torch.randn(2, 1, P, R, generator=torch.Generator().manual_seed(0))
    mask = torch.ones(2, 1, dtype=torch.bool)
    text, empty, own = make_text(2, seed=1), make_text(1, length=2, seed=2), make_text(2, seed=5)
    wa, _ = old.sample(prev, mask, text, empty, generator=torch.Generator().manual_seed(0))
    wb, _ = new.sample(prev, mask, text, empty, generator=torch.Generator().manual_seed(0),
                       person_text=own)  # fmt: skip
    assert torch.allclose(wa, wb, atol=1e-6)  # zero projection: as before
    randomise_projection(new)
    wc, _ = new.sample(prev, mask, text, empty, generator=torch.Generator().manual_seed(0),
                       person_text=own)  # fmt: skip
    assert not torch.allclose(wa, wc, atol=1e-3)
    # the unconditional side of guidance sees no own prompt: at scale 0 it alone remains
    u1, _ = new.sample(prev, mask, text, empty, guidance=0.0,
                       generator=torch.Generator().manual_seed(0), person_text=own)  # fmt: skip
    u2, _ = new.sample(prev, mask, text, empty, guidance=0.0,
                       generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert torch.allclose(u1, u2, atol=1e-6)


def test_toy_only_the_own_prompt_tells_the_action() -> None:
    """One scene prompt for every item; the latent pattern follows the own prompt. After
    training, samples follow the own prompt asked for, and without one they sit between."""
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    patterns = torch.randn(2, P, R, generator=g)
    scene = make_text(1, length=4, seed=7)
    owns = make_text(2, length=4, seed=11)
    empty = make_text(1, length=2, seed=8)
    cfg = PFlowConfig(denoiser=tiny_denoiser(num_layers=2, person_text=True), steps=(6, 4),
                      p_person_drop=0.2)  # fmt: skip
    model = PFlow(cfg, P, R, D_TEXT)
    opt = torch.optim.AdamW(model.parameters(), lr=5e-3)
    b = 16
    text = expand_text(scene, b)
    for _ in range(250):
        cls = torch.randint(0, 2, (b,), generator=g)
        z1 = patterns[cls] + 0.1 * torch.randn(b, P, R, generator=g)
        own = TextFeatures(owns.tokens[cls], owns.mask[cls], owns.pooled[cls])
        loss = model.loss(
            z1,
            text,
            empty,
            torch.ones(b, dtype=torch.long),
            generator=g,
            person_text=own,
            person_present=torch.ones(b, dtype=torch.bool),
        )
        opt.zero_grad()
        loss["total"].backward()
        opt.step()
    two = expand_text(scene, 2)
    z, _ = model.sample(two, empty, num_samples=16, guidance=1.0, generator=g, person_text=owns)
    for c in range(2):
        mean = z[c * 16 : (c + 1) * 16].mean(0)
        right, wrong = (mean - patterns[c]).norm(), (mean - patterns[1 - c]).norm()
        assert right < 0.5 * wrong, (c, float(right), float(wrong))


def test_composed_guidance_sets_the_own_prompts_pull_apart():
    """v_u + s (v_scene - v_u) + s_own (v_both - v_scene), in one forward of three batches;
    with s_own = s it is plain CFG of both prompts against neither."""
    from umf.flows import classifier_free_guidance, composed_guidance

    calls = []

    def velocity(x, t, *, text):
        calls.append(x.shape[0])
        return x * 0 + text[:, None, None]  # the "text" alone decides the velocity

    x, t = torch.zeros(2, 3, 4), torch.zeros(2)
    both, scene, none = (torch.tensor([5.0, 7.0]), torch.tensor([2.0, 3.0]),
                         torch.tensor([1.0, 1.0]))  # fmt: skip
    field = composed_guidance(velocity, 2.0, 4.0, {"text": both}, {"text": scene}, {"text": none})
    v = field(x, t)
    want = none + 2.0 * (scene - none) + 4.0 * (both - scene)  # 15, 21
    assert torch.allclose(v[:, 0, 0], want) and calls == [6]
    same = composed_guidance(velocity, 2.0, 2.0, {"text": both}, {"text": scene}, {"text": none})
    plain = classifier_free_guidance(velocity, 2.0, {"text": both}, {"text": none})
    assert torch.allclose(same(x, t), plain(x, t))


def test_conjoined_guidance_pulls_each_prompt_from_nothing():
    """``conjoin``: v_u + s (v_scene - v_u) + s_own (v_own - v_u), the own prompt a prompt
    of its own (the AND of composable diffusion), in the same one forward of three."""
    from umf.flows import composed_guidance

    calls = []

    def velocity(x, t, *, text):
        calls.append(x.shape[0])
        return x * 0 + text[:, None, None]

    x, t = torch.zeros(2, 3, 4), torch.zeros(2)
    own, scene, none = torch.tensor([5.0, 7.0]), torch.tensor([2.0, 3.0]), torch.tensor([1.0, 1.0])
    field = composed_guidance(velocity, 2.0, 4.0, {"text": own}, {"text": scene},
                              {"text": none}, conjoin=True)  # fmt: skip
    want = none + 2.0 * (scene - none) + 4.0 * (own - none)  # 19, 29: not 15, 21 (joint)
    assert torch.allclose(field(x, t)[:, 0, 0], want) and calls == [6]


def test_a_conjoined_own_prompt_goes_through_the_scene_head_alone():
    """``person_composition`` "and": the own prompt enters as a prompt alone (its token from
    the scene's text head, no person projection), so with ``person_guidance`` 0 the sample
    is the scene prompt's alone; a row without an own prompt is the scene prompt's alone too
    (its own term is the empty prompt's, zero); an unguided stage reads both prompts
    together, as the joint form does."""
    model = pflow(True, person_composition="and")
    randomise_projection(model)  # the projection is not used by the conjoined form
    text, empty, own = make_text(2, seed=1), make_text(1, length=2, seed=2), make_text(2, seed=5)
    g = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    base, _ = model.sample(text, empty, generator=g())
    model.cfg.person_guidance = 0.0
    none, _ = model.sample(text, empty, generator=g(), person_text=own)
    assert torch.allclose(none, base, atol=1e-5)
    model.cfg.person_guidance = 3.0
    conj, _ = model.sample(text, empty, generator=g(), person_text=own)
    model.cfg.person_composition = "joint"
    joint, _ = model.sample(text, empty, generator=g(), person_text=own)
    assert not torch.allclose(conj, base) and not torch.allclose(conj, joint)
    # the own prompt as the scene prompt: conjoined with itself it is plain CFG at 3 + 3
    model.cfg.person_composition = "and"
    same, _ = model.sample(text, empty, generator=g(), person_text=text)
    plain, _ = model.sample(text, empty, generator=g(), guidance=6.0)
    assert torch.allclose(same, plain, atol=1e-4)
    present = torch.tensor([True, False])
    mixed, _ = model.sample(text, empty, generator=g(), person_text=own, person_present=present)
    assert torch.allclose(mixed[0], conj[0], atol=1e-5)
    assert torch.allclose(mixed[1], base[1], atol=1e-5)  # the scene's alone, at 3
    # a stage left unguided (the finest, here) reads scene + own together, not the own alone
    model.cfg.person_composition, model.cfg.fine_guidance = "and", 1.0
    seen, forward = [], model.net.forward

    def spy(x, t, **kw):
        if x.shape[0] == 2:  # a plain call; guided ones run three batches at once
            seen.append(kw["text"])
        return forward(x, t, **kw)

    model.net.forward = spy
    model.sample(text, empty, generator=g(), person_text=own)
    del model.net.forward
    with torch.no_grad():
        model.eval()  # as sampling runs
        joint = model.net.encode_text(text) + model.net.person_token(own, 2)
    assert seen and all(torch.allclose(tok, joint) for tok in seen)


def test_person_guidance_strengthens_only_the_own_prompt():
    """At person_guidance 1 against the scene's, the own prompt pulls less than at 4; a
    sample without an own prompt does not depend on it."""
    model = pflow(True)
    randomise_projection(model)
    text, empty, own = make_text(2, seed=1), make_text(1, length=2, seed=2), make_text(2, seed=5)
    g = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    base, _ = model.sample(text, empty, generator=g())
    pulls = []
    for s_own in (1.0, 4.0):
        model.cfg.person_guidance = s_own
        z, _ = model.sample(text, empty, generator=g(), person_text=own)
        pulls.append(float((z - base).norm()))
        again, _ = model.sample(text, empty, generator=g())
        assert torch.equal(again, base)
    assert pulls[0] < pulls[1]


def test_an_own_head_reads_the_own_prompt_apart_from_the_scene_head() -> None:
    """With ``person_head`` the own token comes through a head of its own: the scene head's
    weights no longer reach it, the own head's do; without own prompts it is not built."""
    model = sflow(True, denoiser=tiny_denoiser(person_text=True, person_head=True))
    net = model.net
    randomise_projection(model)
    own = make_text(2, seed=5)
    before = net.person_token(own, 2)
    with torch.no_grad():
        for p in net.text_head.parameters():
            p.add_(0.5)
    assert torch.equal(net.person_token(own, 2), before)
    with torch.no_grad():
        for p in net.person_head.parameters():
            p.add_(0.5)
    assert not torch.allclose(net.person_token(own, 2), before)
    with pytest.raises(ValueError, match=r"person_head needs denoiser\.person_text"):
        sflow(False, denoiser=tiny_denoiser(person_head=True))


def test_a_new_own_head_restarts_the_projection_after_it() -> None:
    """A fine-tune that adds the own head takes it and the projection as built (zero, so
    the own prompt starts with no effect); one that adds own prompts takes the projection."""
    from umf.train.growth import grown_keys, grown_names

    plain, person = sflow(False).state_dict(), sflow(True).state_dict()
    headed = sflow(True, denoiser=tiny_denoiser(person_text=True, person_head=True))
    keys = grown_keys(headed.state_dict(), person)
    assert {k for k in keys if "person_head" not in k} == {
        "net.person_proj.weight", "net.person_proj.bias"}  # fmt: skip
    assert {k for k in headed.state_dict() if ".person_head." in k} <= set(keys)
    assert sorted(grown_keys(person, plain)) == ["net.person_proj.bias", "net.person_proj.weight"]
    assert grown_keys(person, person) == []
    names = grown_names(keys)
    assert names[:2] == ["net.person_proj.bias", "net.person_proj.weight"]
    assert names[2].startswith("net.person_head.* (") and len(names) == 3


def test_scene_drop_leaves_the_own_prompt_alone() -> None:
    """At p_scene_drop 1 every item with an own prompt trains on it beside the empty scene
    prompt (the same loss as asking so); rows without one keep the scene's."""
    from umf.models.denoiser import drop_text

    z1 = torch.randn(4, P, R, generator=torch.Generator().manual_seed(0))
    text, empty, own = make_text(4, seed=1), make_text(1, length=2, seed=2), make_text(4, seed=5)
    ds = torch.ones(4, dtype=torch.long)
    present = torch.tensor([True, True, False, True])

    def total(scene: TextFeatures, p_scene_drop: float) -> float:
        model = pflow(True, p_uncond=0.0, p_person_drop=0.0, p_scene_drop=p_scene_drop)
        randomise_projection(model)
        gen = torch.Generator().manual_seed(1)
        return float(model.loss(z1, scene, empty, ds, generator=gen, person_text=own,
                                person_present=present)["total"].detach())  # fmt: skip

    alone = total(text, 1.0)
    assert alone == pytest.approx(total(drop_text(text, empty, present), 0.0), rel=1e-6)
    assert alone != pytest.approx(total(text, 0.0), rel=1e-3)
