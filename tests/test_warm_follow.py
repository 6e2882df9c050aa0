"""umf.warm_follow: a partner carried along a turning person 1, and the fall-back pass."""

from __future__ import annotations

import pytest
import torch

from conftest import FakeText, save_tiny_model
from umf.pipeline import UMFPipeline


@pytest.fixture(scope="module")
def pipe(tmp_path_factory):
    return UMFPipeline.from_pretrained(save_tiny_model(tmp_path_factory.mktemp("follow") / "m"),
                                       text_encoder=FakeText())  # fmt: skip


def test_a_twin_draws_what_the_original_draws_next():
    from umf.warm_follow import twin

    gens = [torch.Generator().manual_seed(s) for s in (3, 4)]
    torch.randn(5, generator=gens[0])  # a stream part way through
    twins = twin(gens)
    assert [torch.equal(torch.randn(4, generator=a), torch.randn(4, generator=b))
            for a, b in zip(twins, gens, strict=True)] == [True, True]  # fmt: skip
    one = torch.Generator().manual_seed(9)
    assert torch.equal(torch.randn(3, generator=twin(one)), torch.randn(3, generator=one))
    assert twin(None) is None


def _batch(pipe, rows: int = 3):
    g = torch.Generator().manual_seed(0)
    shape = pipe.vae.latent_shape
    prev = torch.randn(rows, 1, *shape, generator=g)
    mask = torch.ones(rows, 1, dtype=torch.bool)
    text = pipe.text_encoder.encode(["two people run"] * rows)
    uncond = pipe.text_encoder.encode([""])
    straight = torch.randn(rows, *shape, generator=g)
    return prev, mask, text, uncond, straight


def _gens(rows: int = 3):
    return [torch.Generator().manual_seed(10 + i) for i in range(rows)]


def test_a_carried_pass_that_touches_is_sampled_again_from_the_straight_proposal(pipe, monkeypatch):
    """Rows 0 and 2 were carried; row 0's pass touches someone and is taken, so it is
    sampled again from its straight proposal with the draws of the pass it replaces (the
    row is then exactly what a pass from the straight proposal gives); row 2 does not touch,
    row 1 was not carried, and both keep their pass."""
    import umf.warm_follow
    from umf.warm_follow import fall_back, twin

    prev, mask, text, uncond, straight = _batch(pipe)
    frames = 30
    leader = pipe.decode(prev[:, 0], frames, reaction=True)
    seen = []

    def touching(features, everyone, clear):
        seen.append((len(features), everyone.shape[1], clear))
        return torch.tensor([True, False])  # rows 0 and 2, in that order

    monkeypatch.setattr(umf.warm_follow, "touches", touching)
    gens = _gens()
    twins = twin(gens)
    again, _ = pipe.sflow.sample(prev, mask, text, uncond, warm=straight + 1.0, generator=gens)
    kw = {"steps": 2, "guidance": None, "generator": twins}
    rows = torch.tensor([0, 2])
    out, nfe = fall_back(pipe, again, (rows, straight[rows]), torch.ones(3, dtype=torch.bool),
                         prev, mask, text, uncond, frames, leader, None, kw, None)  # fmt: skip
    assert seen == [(2, 1, 0.25)]  # person 1 only; the relation checks' contact distance
    assert nfe > 0
    want, _ = pipe.sflow.sample(prev, mask, text, uncond, warm=straight, generator=_gens(),
                                steps=2, guidance=None)  # fmt: skip
    torch.testing.assert_close(out[0], want[0])
    assert torch.equal(out[1], again[1]) and torch.equal(out[2], again[2])
    assert not torch.allclose(out[0], again[0])


def test_nothing_is_sampled_again_without_a_touch_or_for_a_row_not_taken(pipe, monkeypatch):
    """No carried pass touches, or the one that does is not taken (its first pass is
    kept): the second pass comes back as it was, at no cost. People 2..k - 1's bodies are
    checked beside person 1's."""
    import umf.warm_follow
    from umf.warm_follow import fall_back

    prev, mask, text, uncond, straight = _batch(pipe)
    frames = 30
    leader = pipe.decode(prev[:, 0], frames, reaction=True)
    again = torch.randn(3, *pipe.vae.latent_shape)
    rows = torch.tensor([0, 2])
    kw = {"steps": 2, "guidance": None, "generator": _gens()}
    bodies = torch.zeros(3, 2, frames, 22, 3)
    seen = []

    def nobody(features, everyone, clear):
        seen.append(everyone.shape[1])
        return torch.zeros(len(features), dtype=torch.bool)

    monkeypatch.setattr(umf.warm_follow, "touches", nobody)
    out, nfe = fall_back(pipe, again, (rows, straight[rows]), torch.ones(3, dtype=torch.bool),
                         prev, mask, text, uncond, frames, leader, bodies, kw, None)  # fmt: skip
    assert nfe == 0 and out is again and seen == [3]  # person 1 and people 2..3
    monkeypatch.setattr(umf.warm_follow, "touches",
                        lambda f, e, c: torch.ones(len(f), dtype=torch.bool))  # fmt: skip
    taken = torch.tensor([False, True, False])  # neither carried row takes the second pass
    out, nfe = fall_back(pipe, again, (rows, straight[rows]), taken, prev, mask, text, uncond,
                         frames, leader, None, kw, None)  # fmt: skip
    assert nfe == 0 and out is again


def test_the_pipeline_falls_back_to_exactly_the_straight_pass(pipe, monkeypatch):
    """A proposal that comes back carried (here: shifted) with its straight one beside it:
    where the carried pass touches someone, the scene is exactly the scene of the straight
    proposal alone (the fall-back draws what the replaced pass drew); where it touches
    nobody, the carried pass is kept. Without a straight proposal, fall_back is never run."""
    import numpy as np

    import umf.warm_follow
    import umf.warm_start

    cfg = pipe.config.sflow
    # warm_together: person 1 decoded, whom the carried pass is checked against
    for key, value in {"warm_start": 0.5, "warm_proposal": "pflow", "warm_together": 0.8}.items():
        monkeypatch.setattr(cfg, key, value)

    def scene():
        return pipe("two people run", num_people=3, seconds=1.0, seed=0, fit=False,
                    separate=False)[0].joints  # fmt: skip

    real_fall_back = umf.warm_start.fall_back
    ran = []
    monkeypatch.setattr(umf.warm_start, "fall_back", lambda *a: ran.append(1) or real_fall_back(*a))
    straight = scene()
    assert not ran  # the proposal kept nothing to fall back on
    real = umf.warm_start.proposal

    def carried(*args, **kw):
        z, nfe, fits, lag, _ = real(*args, **kw)
        return z + 1.0, nfe, fits, lag, (torch.arange(len(z)), z)

    monkeypatch.setattr(umf.warm_start, "proposal", carried)
    monkeypatch.setattr(umf.warm_follow, "touches",
                        lambda f, e, c: torch.ones(len(f), dtype=torch.bool))  # fmt: skip
    assert np.array_equal(scene(), straight)  # persons 2 and 3 fell back, same draws
    monkeypatch.setattr(umf.warm_follow, "touches",
                        lambda f, e, c: torch.zeros(len(f), dtype=torch.bool))  # fmt: skip
    kept = scene()
    assert np.array_equal(kept[0], straight[0]) and not np.allclose(kept[1:], straight[1:])
