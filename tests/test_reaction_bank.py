"""Real reactions for the warm start (``sflow.warm_proposal = "retrieved"``): the bank's
file, its nearest reactions, its build from a corpus, the pipeline and the CLI."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import MODULE, FakeText, prepare_fixture_corpus, save_tiny_model
from umf.data.relations import SIDE_MARGIN
from umf.errors import UMFError
from umf.pipeline import UMFPipeline
from umf.reaction_bank import REACTIONS, ReactionBank
from umf.train.reactions import bank_lengths, build_reaction_bank

pytestmark = pytest.mark.usefixtures("one_thread")
P, R = 4, 8


def nearest(bank: ReactionBank, query: torch.Tensor, frames: int, neighbours: int, *args,
            **kwargs) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """:meth:`ReactionBank.pick`'s reactions (B, p, r) and whether each row had one at pace."""
    length, idx, at_pace = bank.pick(query, frames, neighbours, *args, **kwargs)
    return bank.latents[length][idx], at_pace


def _bank(seed: int = 0) -> ReactionBank:
    g = torch.Generator().manual_seed(seed)
    return ReactionBank({30: torch.randn(50, P, R, generator=g),
                         60: torch.randn(20, P, R, generator=g)})  # fmt: skip


def test_the_bank_round_trips_through_its_file(tmp_path):
    bank = _bank()
    path = bank.save(tmp_path)
    assert path == tmp_path / REACTIONS
    back = ReactionBank.load(tmp_path, (P, R))
    assert back.lengths() == [30, 60]
    for k in (30, 60):  # stored in fp16
        torch.testing.assert_close(back.latents[k], bank.latents[k], atol=2e-3, rtol=1e-3)
    assert ReactionBank.load(tmp_path / "nowhere") is None
    with pytest.raises(UMFError, match="do not fit the model"):
        ReactionBank.load(tmp_path, (P, R + 1))
    path.write_bytes(b"not a safetensors file")
    with pytest.raises(UMFError, match="corrupt reaction bank"):
        ReactionBank.load(tmp_path)


def test_nearest_takes_the_stored_length_nearest_and_one_of_the_k_nearest():
    bank = _bank()
    assert [bank.bucket(f) for f in (1, 30, 44, 45, 46, 500)] == [30, 30, 30, 30, 60, 60]
    store = bank.latents[30]
    query = store[[3, 7, 11]] + 0.01 * torch.randn(
        3, P, R, generator=torch.Generator().manual_seed(1)
    )
    assert torch.equal(nearest(bank, query, 33, 1)[0], store[[3, 7, 11]])
    d = torch.cdist(query.flatten(1), store.flatten(1))
    near = d.topk(5, largest=False).indices
    gens = [torch.Generator().manual_seed(s) for s in range(3)]
    got = nearest(bank, query, 33, 5, gens)[0]
    for row, z in enumerate(got):
        i = int((store == z).all(dim=(1, 2)).nonzero())
        assert i in near[row].tolist()
    again = nearest(bank, query, 33, 5, [torch.Generator().manual_seed(s) for s in range(3)])[0]
    assert torch.equal(got, again)  # seeded, row by row
    picks = {int((store == nearest(bank, query[:1], 33, 5, torch.Generator().manual_seed(s))[0][0])
                 .all(dim=(1, 2)).nonzero()) for s in range(40)}  # fmt: skip
    assert picks == set(near[0].tolist())  # every one of the 5 is drawn
    # the distance is measured after ``scale``: one that weighs channel 0 a thousandfold
    weigh = torch.ones(R)
    weigh[0] = 1000.0
    far = torch.randn(3, P, R, generator=torch.Generator().manual_seed(9))
    scaled = nearest(bank, far, 33, 1, scale=lambda z: z * weigh)[0]
    want = torch.cdist((far * weigh).flatten(1), (store * weigh).flatten(1)).argmin(dim=1)
    plain = torch.cdist(far.flatten(1), store.flatten(1)).argmin(dim=1)
    assert torch.equal(scaled, store[want]) and not torch.equal(want, plain)


@pytest.fixture(scope=MODULE)
def corpus(tmp_path_factory):
    return prepare_fixture_corpus(tmp_path_factory.mktemp("bank") / "corpus", train_scenes=8,
                                  val_scenes=2, test_scenes=2, test_groups=2)  # fmt: skip


@pytest.fixture(scope=MODULE)
def model(tmp_path_factory):
    """A tiny model that warm-starts from retrieved reactions (no bank yet)."""
    path = save_tiny_model(tmp_path_factory.mktemp("bank") / "model", seed=3)
    cfg = json.loads((path / "config.json").read_text())
    cfg["sflow"] |= {"warm_start": 0.5, "warm_proposal": "retrieved", "warm_neighbours": 2}
    (path / "config.json").write_text(json.dumps(cfg))
    return path


def test_the_bank_holds_people_2_to_n_of_the_train_scenes_as_posterior_means(corpus, model):
    from umf.data.corpus import Corpus
    from umf.train.datasets import SceneDataset

    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    bank = build_reaction_bank(corpus, pipe, lengths=[30, 60], per_length=10_000,
                               progress=False, log=lambda m: None)  # fmt: skip
    assert bank.lengths() == [30, 60]
    ds = SceneDataset(Corpus.load(corpus), "train", pipe.normalizer, min_frames=30,
                      max_frames=30, mirror=True, seed=0)  # fmt: skip
    people = torch.cat([ds[i]["features"][1:] for i in range(len(ds))
                        if ds[i]["features"].shape[1] == 30])  # fmt: skip
    with torch.no_grad():
        want = pipe.vae.encode(people, torch.ones(people.shape[:2], dtype=torch.bool))[0]
    torch.testing.assert_close(bank.latents[30], want, atol=1e-5, rtol=1e-5)
    captions = [ds[i]["caption"] for i in range(len(ds)) if ds[i]["features"].shape[1] == 30
                for _ in ds[i]["features"][1:]]  # fmt: skip
    from umf.coverage import embed

    torch.testing.assert_close(bank.texts[30], embed(pipe.text_encoder, captions))
    small = build_reaction_bank(corpus, pipe, lengths=[30], per_length=5, progress=False,
                                log=lambda m: None)  # fmt: skip
    assert small.latents[30].shape == (5, *pipe.vae.latent_shape)
    rows = [int(((want - z).abs().amax(dim=(1, 2)) < 1e-5).nonzero()[0]) for z in small.latents[30]]
    assert rows == sorted(set(rows))  # distinct reactions, in the corpus's order
    assert bank_lengths(120) == [30, 45, 60, 75, 90, 105, 120]


def test_the_pipeline_warm_starts_from_a_real_reaction(corpus, model, tmp_path, monkeypatch):
    import umf.warm_start

    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    with pytest.raises(UMFError, match=r"no reactions\.safetensors"):
        pipe("two people walk side by side", num_people=2, seconds=1.0, seed=0)
    pipe.reactions = build_reaction_bank(corpus, pipe, lengths=[30, 45], progress=False,
                                         log=lambda m: None)  # fmt: skip
    proposals = []
    real = umf.warm_start.proposal

    def seen(*args, **kw):
        z, nfe, fits, lag, straight = real(*args, **kw)
        proposals.append(z)
        return z, nfe, fits, lag, straight

    monkeypatch.setattr(umf.warm_start, "proposal", seen)
    a = pipe("two people walk side by side", num_people=3, seconds=1.0, seed=0, fit=False)[0]
    assert len(proposals) == 2 and a.meta["nfe"] == 6 + 2 * (3 + 2)  # no P-Flow proposal
    store = pipe.reactions.latents[30]
    for z in proposals:  # each a stored reaction of the nearest length
        assert bool((store[None] == z[:, None]).all(dim=(2, 3)).any(dim=1).all())
    b = pipe("two people walk side by side", num_people=3, seconds=1.0, seed=0, fit=False)[0]
    assert np.array_equal(a.joints, b.joints)
    cold = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    cold.config.sflow.warm_start = 0.0
    c = cold("two people walk side by side", num_people=3, seconds=1.0, seed=0, fit=False)[0]
    assert np.array_equal(a.joints[0], c.joints[0]) and not np.allclose(a.joints[1:], c.joints[1:])
    out = pipe.save_pretrained(tmp_path / "saved")
    again = UMFPipeline.from_pretrained(out, text_encoder=FakeText())
    assert again.reactions.lengths() == [30, 45]


def test_the_cli_writes_a_models_bank(corpus, model, tmp_path, fake_text):
    from typer.testing import CliRunner

    from umf.cli.main import app

    copy = Path(shutil.copytree(model, tmp_path / "model"))
    r = CliRunner().invoke(app, ["train", "reactions", "--model", str(copy), "--corpus",
                                 str(corpus), "--per-length", "7", "--no-progress"])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "reactions of" in r.output and (copy / REACTIONS).exists()
    bank = ReactionBank.load(copy)
    assert max(len(z) for z in bank.latents.values()) <= 7
    r = CliRunner().invoke(app, ["train", "reactions", "--model", str(copy), "--corpus",
                                 str(corpus), "--per-length", "0"])  # fmt: skip
    assert r.exit_code != 0  # a one-line error through the entry point (test_cli.py)
    assert isinstance(r.exception, UMFError) and "--per-length" in str(r.exception)


def test_a_shortlist_by_caption_restricts_the_candidates(tmp_path):
    """With captions, only the ``shortlist`` reactions whose captions are nearest the prompt
    compete; without a prompt or captions, every reaction does; captions round-trip."""
    g = torch.Generator().manual_seed(4)
    latents = torch.randn(30, P, R, generator=g)
    texts = torch.nn.functional.normalize(torch.randn(30, 16, generator=g), dim=-1)
    bank = ReactionBank({30: latents}, {30: texts})
    query = latents[[5]] + 0.01
    assert torch.equal(nearest(bank, query, 30, 1)[0], latents[[5]])
    prompt = torch.nn.functional.normalize(torch.randn(1, 16, generator=g), dim=-1)
    short = (prompt @ texts.T).topk(2).indices[0]  # the two captions nearest the prompt
    assert 5 not in short.tolist()
    got = nearest(bank, query, 30, 1, prompt=prompt, shortlist=2)[0]
    d = torch.cdist(query.flatten(1), latents[short].flatten(1))
    assert torch.equal(got, latents[short][d.argmin(dim=1)])
    picks = {int((latents == nearest(bank, query, 30, 4, torch.Generator().manual_seed(s),
                                          prompt=prompt, shortlist=2)[0][0]).all(dim=(1, 2))
                 .nonzero()) for s in range(20)}  # fmt: skip
    assert picks == set(short.tolist())  # 4 neighbours asked, 2 on the shortlist
    plain = ReactionBank({30: latents})  # no captions: the shortlist is ignored
    assert torch.equal(nearest(plain, query, 30, 1, prompt=prompt, shortlist=2)[0], latents[[5]])
    bank.save(tmp_path)
    back = ReactionBank.load(tmp_path, (P, R))
    torch.testing.assert_close(back.texts[30], texts, atol=2e-3, rtol=1e-3)
    ReactionBank({30: latents}, {30: texts[:10]}).save(tmp_path)
    with pytest.raises(UMFError, match="captions of 30 frames"):
        ReactionBank.load(tmp_path)


def _captioned(angles: list[float]) -> torch.Tensor:
    """Unit caption embeddings (N, 2) at these angles (radians) from the x axis."""
    a = torch.tensor(angles)
    return torch.stack([a.cos(), a.sin()], dim=1)


def test_a_margin_keeps_a_far_prompt_to_its_nearest_captions():
    """A prompt worded like no caption (cosine below 1 - margin to all) shortlists only the
    captions within the margin of its nearest one; a prompt worded like a caption keeps the
    whole shortlist; margin 0 changes nothing."""
    # 6 reactions: 3 of caption A (0 rad), 3 of caption B (0.6 rad: cosine 0.83 to A)
    texts = _captioned([0.0, 0.0, 0.0, 0.6, 0.6, 0.6])
    latents = torch.zeros(6, P, R)
    latents[:, 0, 0] = torch.arange(6.0)
    bank = ReactionBank({30: latents}, {30: texts})
    query = latents[[4]]  # the first pass is nearest reaction 4 (caption B)

    def picks(prompt, margin):
        got = [nearest(bank, query, 30, 6, torch.Generator().manual_seed(s), prompt=prompt,
                       shortlist=6, margin=margin)[0] for s in range(40)]  # fmt: skip
        return {int(g[0, 0, 0]) for g in got}

    far = _captioned([-0.45])  # cosine 0.90 to A, 0.50 to B: worded like neither
    assert picks(far, 0.0) == set(range(6))
    assert picks(far, 0.05) == {0, 1, 2}  # only A's: B is 0.40 further than A
    assert picks(far, 0.4) == set(range(6))  # within 0.4 of A: worded like a caption
    assert picks(_captioned([0.0]), 0.05) == set(range(6))  # A's own wording: all compete
    listed = bank._shortlisted(30, torch.cat([far, _captioned([0.0])]), 6, query.flatten(1),
                               margin=0.05)  # fmt: skip
    assert listed.tolist() == [[True] * 3 + [False] * 3, [True] * 6]  # row by row


def test_a_pace_restricts_the_candidates_to_reactions_travelling_as_the_first_pass(tmp_path):
    """With velocities, only reactions whose pelvis velocity is within ``pace`` x the
    query's speed of it compete (speed and direction), and the ``neighbours`` nearest in
    velocity where fewer are; velocities round-trip and a bank whose velocities do not match
    its reactions is refused."""
    g = torch.Generator().manual_seed(5)
    latents = torch.randn(40, P, R, generator=g)
    speed = torch.linspace(0.0, 1.95, 40)  # reaction i travels at 0.05 i m/s ...
    sign = torch.where(torch.arange(40) % 2 == 0, 1.0, -1.0)  # ... forward (even) or back
    velocities = torch.stack([torch.zeros(40), sign * speed], dim=1)
    bank = ReactionBank({30: latents}, velocities={30: velocities})
    query = latents[[3, 3]] + 0.01  # nearest in latent space: reaction 3 (0.15 m/s back)
    assert torch.equal(nearest(bank, query, 30, 1)[0], latents[[3, 3]])
    want = torch.tensor([[0.0, 1.2], [0.0, -1.2]])  # 1.2 m/s forward, 1.2 m/s back
    got = nearest(bank, query, 30, 1, velocity=want, pace=0.2)[0]
    for row in range(2):
        ok = ((velocities - want[row]).norm(dim=-1) <= 0.2 * 1.2 + 1e-6).nonzero()[:, 0]
        assert (velocities[ok, 1] * want[row, 1] > 0).all() and len(ok) >= 3
        d = torch.cdist(query[row : row + 1].flatten(1), latents[ok].flatten(1))
        assert torch.equal(got[row], latents[ok][d.argmin()])
    # nothing within 1 % of 3 m/s forward: the 3 fastest forward ones compete
    picks = {int((latents == nearest(bank, query[:1], 30, 3, torch.Generator().manual_seed(s),
                                          velocity=torch.tensor([[0.0, 3.0]]), pace=0.01)[0][0])
                 .all(dim=(1, 2)).nonzero()) for s in range(30)}  # fmt: skip
    assert picks == {34, 36, 38}
    plain = ReactionBank({30: latents})  # no velocities: the pace is ignored
    assert torch.equal(nearest(plain, query, 30, 1, velocity=want, pace=0.2)[0], latents[[3, 3]])
    bank.save(tmp_path)
    torch.testing.assert_close(ReactionBank.load(tmp_path).velocities[30], velocities,
                               atol=2e-3, rtol=1e-3)  # fmt: skip
    ReactionBank({30: latents}, velocities={30: velocities[:, :1]}).save(tmp_path)
    with pytest.raises(UMFError, match="velocities of 30 frames"):
        ReactionBank.load(tmp_path)


def test_the_bank_stores_each_reactions_pelvis_velocity(corpus, model):
    from umf.data.corpus import Corpus
    from umf.representation import features_to_joints
    from umf.train.datasets import SceneDataset

    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    bank = build_reaction_bank(corpus, pipe, lengths=[30], per_length=10_000, progress=False,
                               log=lambda m: None)  # fmt: skip
    ds = SceneDataset(Corpus.load(corpus), "train", pipe.normalizer, min_frames=30,
                      max_frames=30, mirror=True, seed=0)  # fmt: skip
    people = torch.cat([ds[i]["features"][1:] for i in range(len(ds))
                        if ds[i]["features"].shape[1] == 30])  # fmt: skip
    pelvis = features_to_joints(pipe.normalizer.denormalize(people))[:, :, 0][..., [0, 2]]
    want = (pelvis[:, -1] - pelvis[:, 0]) * pipe.config.fps / 29
    torch.testing.assert_close(bank.velocities[30], want, atol=1e-5, rtol=1e-5)
    assert bank.velocities[30].norm(dim=-1).max() > 0.1  # the fixture's people travel
    torch.testing.assert_close(bank.starts[30], pelvis[:, 0], atol=1e-5, rtol=1e-5)
    assert (bank.starts[30][:, 0] > 0).any() and (bank.starts[30][:, 0] < 0).any()  # both sides


def at_pace(bank, velocity, frames, pace, prompt=None, shortlist=0):
    """Whether :meth:`ReactionBank.nearest` found each row a reaction at ``pace``."""
    query = torch.zeros(len(velocity), *next(iter(bank.latents.values())).shape[1:])
    return nearest(bank, query, frames, 1, prompt=prompt, shortlist=shortlist,
                        velocity=velocity, pace=pace)[1]  # fmt: skip


def test_nearest_says_which_rows_the_bank_has_a_reaction_at_pace_for():
    v = torch.tensor([[0.0, 0.0], [0.0, 1.0], [0.0, -2.0]])
    bank = ReactionBank({30: torch.zeros(3, P, R)}, velocities={30: v})
    rows = torch.tensor([[0.0, 1.1], [0.0, -2.3], [0.0, 2.0], [0.0, 0.5], [0.1, -2.05]])
    assert at_pace(bank, rows, 33, 0.15).tolist() == [True, True, False, False, True]
    no_velocities = ReactionBank({30: torch.zeros(3, P, R)})
    assert at_pace(no_velocities, torch.tensor([[9.0, 0.0]]), 30, 0.1).all()


def test_captions_are_stored_once_and_a_bad_row_is_refused(tmp_path):
    from safetensors.torch import load_file, save_file

    latents = torch.randn(6, P, R, generator=torch.Generator().manual_seed(2))
    two = torch.nn.functional.normalize(torch.randn(2, 16), dim=-1)
    bank = ReactionBank({30: latents[:4], 60: latents[4:]},
                        {30: two[[0, 0, 1, 0]], 60: two[[1, 1]]})  # fmt: skip
    path = bank.save(tmp_path)
    raw = load_file(str(path))
    assert raw["captions"].shape == (2, 16)  # two distinct captions, each stored once
    back = ReactionBank.load(tmp_path)
    for k in (30, 60):
        torch.testing.assert_close(back.texts[k], bank.texts[k], atol=2e-3, rtol=1e-3)
    raw["caption_30"] = torch.tensor([0, 1, 2, 0], dtype=torch.int32)
    save_file(raw, str(path))
    with pytest.raises(UMFError, match="corrupt reaction bank"):
        ReactionBank.load(tmp_path)


def test_a_finetune_on_solo_clips_keeps_the_base_bank_or_turns_the_warm_start_off(
    model, tmp_path, monkeypatch
):
    """A corpus without multi-person train scenes has no reactions: the fine-tuned model
    keeps the base model's bank where its VAE is the base's, and otherwise samples without
    the warm start; either way it loads and generates."""
    import umf.train.reactions as reactions
    from umf.train.run import give_reactions

    base = Path(shutil.copytree(model, tmp_path / "base"))
    ReactionBank({30: torch.randn(5, *UMFPipeline.from_pretrained(
        base, text_encoder=FakeText()).vae.latent_shape)}).save(base)  # fmt: skip

    def none(*args, **kwargs):
        raise reactions.NoReactions("no multi-person train scene")

    monkeypatch.setattr(reactions, "write_reactions", none)
    for own_vae in (False, True):
        out = Path(shutil.copytree(model, tmp_path / f"out-{own_vae}"))
        cfg = json.loads((out / "config.json").read_text())  # as the bundled model samples
        cfg["sflow"] |= {"warm_pace": 0.15, "warm_together": 0.8}
        (out / "config.json").write_text(json.dumps(cfg))
        logs: list[str] = []
        give_reactions(out, tmp_path, base, own_vae, False, logs.append)
        cfg = json.loads((out / "config.json").read_text())
        if own_vae:  # a fine-tuned VAE: the base's latents no longer fit
            assert not (out / REACTIONS).exists() and cfg["sflow"]["warm_start"] == 0.0
        else:
            assert (out / REACTIONS).read_bytes() == (base / REACTIONS).read_bytes()
            assert cfg["sflow"]["warm_start"] == 0.5
        assert logs and "no multi-person train scene" in logs[0]
        (scene,) = UMFPipeline.from_pretrained(out, text_encoder=FakeText())(
            "two people walk", num_people=2, seconds=1.0, seed=0, fit=False)  # fmt: skip
        assert np.isfinite(scene.joints).all()


def test_a_corpus_without_scenes_has_no_reactions(model, tmp_path):
    from umf.train.reactions import NoReactions

    solo = prepare_fixture_corpus(tmp_path / "solo", train_scenes=1, val_scenes=1,
                                  test_scenes=1, test_groups=1)  # fmt: skip
    scenes = json.loads((solo / "scenes.json").read_text())
    (solo / "scenes.json").write_text(json.dumps({**scenes, "train": []}))  # solo clips only
    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    with pytest.raises(NoReactions, match="no multi-person train scene"):
        build_reaction_bank(solo, pipe, lengths=[30], progress=False, log=lambda m: None)


def test_the_pace_looks_only_inside_the_caption_shortlist():
    """With a shortlist and a pace, a reaction at pace outside the shortlist neither
    qualifies a row nor is chosen."""
    latents = torch.randn(4, P, R, generator=torch.Generator().manual_seed(3))
    texts = torch.eye(4, 16)  # reaction i's caption is unit vector i
    velocities = torch.tensor([[0.0, 0.0], [0.0, 0.2], [0.0, 1.4], [0.0, 1.8]])
    bank = ReactionBank({30: latents}, {30: texts}, {30: velocities})
    prompt = torch.nn.functional.normalize(torch.tensor([[1.0, 0.9, 0.8] + [0.0] * 13]), dim=-1)
    fast = torch.tensor([[0.0, 1.8]])  # only reaction 3 is at pace, and it is not shortlisted
    assert at_pace(bank, fast, 30, 0.15).tolist() == [True]
    assert at_pace(bank, fast, 30, 0.15, prompt, shortlist=3).tolist() == [False]
    assert at_pace(bank, torch.tensor([[0.0, 1.5]]), 30, 0.15, prompt, 3).tolist() == [True]
    query = latents[[3]] + 0.01
    assert torch.equal(nearest(bank, query, 30, 1, velocity=fast, pace=0.15)[0], latents[[3]])
    got = nearest(bank, query, 30, 1, prompt=prompt, shortlist=3, velocity=fast, pace=0.15)[0]
    assert torch.equal(got, latents[[2]])  # the shortlisted reaction nearest in velocity
    # a slow row: the tolerance is a share of at least PACE_FLOOR m/s, not of its own speed
    from umf.reaction_bank import PACE_FLOOR

    slow = torch.tensor([[0.0, 0.05]])
    assert at_pace(bank, slow, 30, 0.2).tolist() == [True]  # 0 and 0.2 m/s within 0.1 of 0.05
    assert at_pace(bank, slow, 30, 0.2 * 0.05 / PACE_FLOOR).tolist() == [False]


def test_a_legacy_bank_with_a_caption_per_reaction_loads_and_bad_rows_are_refused(tmp_path):
    from safetensors.torch import save_file

    latents = torch.randn(3, P, R, generator=torch.Generator().manual_seed(6)).half()
    texts = torch.nn.functional.normalize(torch.randn(3, 16), dim=-1).half()
    save_file({"frames_30": latents, "text_30": texts}, str(tmp_path / REACTIONS))
    back = ReactionBank.load(tmp_path, (P, R))
    assert torch.equal(back.texts[30], texts.float()) and back.velocities == {}
    for rows in (torch.tensor([0.0, 1.5, 0.0]), torch.tensor([0, 1, 2]).int()[None]):
        save_file({"frames_30": latents, "captions": texts, "caption_30": rows},
                  str(tmp_path / REACTIONS))  # fmt: skip
        with pytest.raises(UMFError, match="corrupt reaction bank"):
            ReactionBank.load(tmp_path)


def test_a_prompt_naming_a_side_retrieves_reactions_on_that_side():
    """``mirror``: only captions at least as near the prompt as its mirror image compete, so
    the retrieval keeps to the named side even when the other side's reaction is the nearest
    in latent space; captions naming no side stay in; a prompt that is its own mirror image
    changes nothing. The composer's captions, embedded by the tests' text encoder."""
    from umf.coverage import embed
    from umf.text import mirror_caption

    encoder = FakeText()
    left = "Two people walk side by side, the second person on the first one's left."
    right, plain = mirror_caption(left), "Two people walk side by side."
    captions = embed(encoder, [left, right, plain])  # unit rows
    g = torch.Generator().manual_seed(6)
    latents = torch.randn(3, P, R, generator=g)
    bank = ReactionBank({30: latents}, {30: captions})
    query = latents[[1]] + 0.01  # nearest in latent space: the reaction on the right
    prompt, mirror = embed(encoder, [left]), embed(encoder, [right])
    near = nearest(bank, query, 30, 1, prompt=prompt, shortlist=3)[0]
    assert torch.equal(near, latents[[1]])
    sided = nearest(bank, query, 30, 1, prompt=prompt, shortlist=3, mirror=mirror)[0]
    kept = [i for i in range(3) if float(captions[i] @ prompt[0]) >= float(captions[i] @ mirror[0])]
    assert 1 not in kept and 0 in kept
    d = torch.cdist(query.flatten(1), latents[kept].flatten(1))
    assert torch.equal(sided, latents[kept][d.argmin(dim=1)])
    assert torch.equal(nearest(bank, query, 30, 1, prompt=embed(encoder, [plain]), shortlist=3,
                                    mirror=embed(encoder, [plain]))[0], latents[[1]])  # fmt: skip


def test_a_rows_pick_does_not_depend_on_the_others_in_its_batch():
    """Row 0 draws the same reaction whether its batch partner's shortlist is full or holds
    fewer reactions than the neighbours asked (a side with few captions), per-row seeds."""
    g = torch.Generator().manual_seed(7)
    latents = torch.randn(40, P, R, generator=g)
    raw = torch.randn(40, 16, generator=g)
    raw[:, 0] = raw[:, 0].abs() + 0.1
    raw[:2, 0] = -raw[:2, 0]  # captions 0 and 1 lean the other way along axis 0
    texts = torch.nn.functional.normalize(raw, dim=-1)
    bank = ReactionBank({30: latents}, {30: texts})
    query = latents[[0, 1]] + 0.01
    prompt = torch.nn.functional.normalize(torch.randn(2, 16, generator=g), dim=-1)
    far = prompt[1:] + 10.0 * torch.eye(16)[:1]  # a mirror image nearer for all but 0 and 1
    near_side = (prompt[1] @ texts.T >= far[0] @ texts.T).nonzero()[:, 0].tolist()
    assert near_side == [0, 1]  # the partner keeps 2 captions on its side, 4 neighbours asked
    picks = []
    for partner_mirror in (prompt[1:], far):
        mirror = torch.cat([prompt[:1], partner_mirror])
        for seed in range(6):
            gens = [torch.Generator().manual_seed(seed), torch.Generator().manual_seed(99)]
            z, _ = nearest(bank, query, 30, 4, gens, prompt=prompt, shortlist=40, mirror=mirror)
            picks.append((partner_mirror is far, seed, z[0]))
    for seed in range(6):
        a, b = (z for far_, s, z in picks if s == seed)
        assert torch.equal(a, b), seed


def test_the_bank_stores_how_long_each_answer_waited_in_its_whole_scene(corpus, model, tmp_path):
    """``lags``: per reaction whose relation answers person 1 (a starts_after check on it),
    its action onset minus person 1's in the whole scene it was cropped from (as the checks
    read onsets), whatever the crop cut; 0 for everybody else. Kept by the file; a row of
    the wrong length refused."""
    from safetensors.torch import load_file, save_file

    from umf.data.corpus import Corpus
    from umf.train.datasets import SceneDataset
    from umf.warm_start import onsets

    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    bank = build_reaction_bank(corpus, pipe, lengths=[30], per_length=10_000, progress=False,
                               log=lambda m: None)  # fmt: skip
    ds = SceneDataset(Corpus.load(corpus), "train", pipe.normalizer, min_frames=30,
                      max_frames=30, mirror=True, seed=0)  # fmt: skip
    want, needed = [], []
    for i in range(len(ds)):
        if ds[i]["features"].shape[1] != 30:
            continue
        _, record, _ = ds.items[i]
        start = onsets(ds.whole(i))
        waits = {c["b"]: c["min_frames"] for c in record["constraints"]
                 if c["type"] == "starts_after"}  # fmt: skip
        want += [o - start[0] if k in waits else 0 for k, o in enumerate(start[1:], 1)]
        needed += [(len(want) - len(start) + k, m) for k, m in waits.items()]
    assert bank.lags[30].tolist() == want
    assert needed  # the fixture's composed scenes hold answers
    # each answer waited at least what its composer's record asks (its starts_after check)
    assert all(bank.lags[30][row] >= m >= 5 for row, m in needed), needed
    path = bank.save(tmp_path)
    assert torch.equal(ReactionBank.load(tmp_path).lags[30], bank.lags[30])
    raw = load_file(str(path))
    raw["lag_30"] = raw["lag_30"][:-1]
    save_file(raw, str(path))
    with pytest.raises(UMFError, match="lags of 30 frames do not match"):
        ReactionBank.load(tmp_path)


def test_caption_waits_and_where_the_bank_keeps_a_prompts_captions():
    """``caption_waits``: the median wait of the reactions of the prompt's nearest caption
    (ties), and how many; ``caption_length``: the stored length nearest the request among
    those that hold that caption; ``pick`` / ``lag``: a reaction's index and its wait."""
    g = torch.Generator().manual_seed(8)
    spar, walk = torch.nn.functional.normalize(torch.tensor([[1.0, 0.0], [0.0, 1.0]]), dim=-1)
    near_spar = torch.nn.functional.normalize(torch.tensor([1.0, 0.3]), dim=0)
    bank = ReactionBank(
        {285: torch.randn(5, P, R, generator=g), 300: torch.randn(3, P, R, generator=g)},
        {285: torch.stack([spar, spar, spar, near_spar, walk]), 300: torch.stack([walk] * 3)},
        lags={285: torch.tensor([20.0, 30.0, 26.0, 0.0, 0.0]), 300: torch.zeros(3)},
    )
    prompts = torch.stack([spar, walk])
    median, count = bank.caption_waits(285, prompts)
    assert median.tolist() == [26.0, 0.0] and count.tolist() == [3, 1]
    assert bank.caption_length(300, prompts) == [285, 300]  # no spar stored at 300
    assert bank.caption_length(290, prompts[1:]) == [285]  # walks at both: the nearest
    assert ReactionBank({30: torch.zeros(2, P, R)}).caption_waits(30, prompts) is None
    length, idx, _ = bank.pick(bank.latents[285][[2, 4]] + 0.01, 280, 1)
    assert length == 285 and idx.tolist() == [2, 4]
    assert bank.lag(length, idx).tolist() == [26.0, 0.0]


def test_an_answer_is_retrieved_where_its_caption_is_stored_with_its_wait():
    """``umf.warm_start.answers``: a spar asked for 300 frames takes one of the spar
    reactions stored at 285 and its wait; a walk keeps its reaction and waits 0; below
    ``warm_timing`` nobody answers."""
    from types import SimpleNamespace

    from umf.warm_start import answers

    g = torch.Generator().manual_seed(9)
    spar, walk = torch.nn.functional.normalize(torch.tensor([[1.0, 0.0], [0.0, 1.0]]), dim=-1)
    bank = ReactionBank(
        {285: torch.randn(4, P, R, generator=g), 300: torch.randn(2, P, R, generator=g)},
        {285: torch.stack([spar, spar, walk, walk]), 300: torch.stack([walk, walk])},
        lags={285: torch.tensor([18.0, 24.0, 0.0, 0.0]), 300: torch.zeros(2)},
    )
    first = bank.latents[285][[1, 2]] + 0.01  # a first pass nearest spar 1, one near a walk
    z0 = bank.latents[300][[0, 1]]  # what the usual retrieval at 300 frames gave
    cfg = SimpleNamespace(warm_timing=8.0, warm_neighbours=1)
    z, waits, stored = answers(bank, first, 300, z0, cfg, None, lambda x: x,
                               torch.stack([spar, walk]))  # fmt: skip
    assert torch.equal(z[0], bank.latents[285][1]) and waits.tolist() == [24.0, 0.0]
    assert stored == [285, 300]
    assert torch.equal(z[1], z0[1])
    cfg.warm_timing = 30.0  # the spars waited 18 frames at the (lower) median: no answer
    z, waits, _ = answers(bank, first, 300, z0, cfg, None, lambda x: x,
                          torch.stack([spar, walk]))  # fmt: skip
    assert torch.equal(z, z0) and not waits.any()


def test_the_pipeline_retimes_answers_and_only_answers(corpus, model):
    """End to end on a tiny model: with ``sflow.warm_timing`` a prompt whose caption's
    reactions wait gets another person 2 (its answer retimed and taken), a prompt whose
    don't is sampled as without it, and re-rolling person 1 (who answers nobody) too."""
    from umf.coverage import embed
    from umf.data.corpus import Corpus

    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    pipe.reactions = build_reaction_bank(corpus, pipe, lengths=[30, 45], progress=False,
                                         log=lambda m: None)  # fmt: skip
    scenes = Corpus.load(corpus).scenes["train"]
    waits = {r["captions"][0] for r in scenes
             if any(c["type"] == "starts_after" for c in r["constraints"])}  # fmt: skip
    still = {r["captions"][0] for r in scenes} - waits
    assert waits and still
    answer, other = sorted(waits)[0], sorted(still)[0]
    median = pipe.reactions.caption_waits(30, embed(pipe.text_encoder, [answer]))[0]
    assert float(median[0]) >= 1  # the fixture's answer waits
    cfg = pipe.config.sflow

    source = pipe(answer, num_people=2, seconds=1.0, seed=0, fit=False, separate=False)[0]

    def both(prompt: str, person: int | None = None):
        out = []
        for timing in (0.0, 1.0):
            cfg.warm_timing = timing
            if person is None:
                out.append(pipe(prompt, num_people=2, seconds=1.0, seed=0, fit=False,
                                separate=False)[0])  # fmt: skip
            else:
                out.append(pipe.reroll(source, person, seed=3, anchor=False, separate=False))
        cfg.warm_timing = 0.0
        return out

    off, on = both(answer)
    assert np.array_equal(off.joints[0], on.joints[0]) and not np.allclose(
        off.joints[1], on.joints[1]
    )
    off, on = both(other)
    assert np.array_equal(off.joints, on.joints)
    off, on = both(answer, person=1)  # person 1 re-rolled: the same with the option
    assert np.array_equal(off.joints, on.joints)
    off, on = both(answer, person=2)  # person 2 re-rolled: answers again
    assert not np.allclose(off.joints[1], on.joints[1])


def test_stand_keeps_each_rows_reaction_on_its_side_of_person_1(tmp_path):
    """``pick(stand=)``: +1 retrieves among reactions starting on person 1's left (+x), -1 on
    the right, 0 anywhere; a row with nobody on its side keeps every candidate. The starts
    round-trip through the file and a bad table is refused."""
    g = torch.Generator().manual_seed(3)
    latents = torch.randn(40, P, R, generator=g)
    starts = torch.stack([torch.linspace(-2, 2, 40), torch.zeros(40)], dim=1)
    starts[20] = torch.tensor([0.3, 0.0])  # the nearest to every query below stands left
    bank = ReactionBank({30: latents}, starts={30: starts})
    query = latents[20:21].expand(3, -1, -1) + 0.01
    stand = torch.tensor([1.0, -1.0, 0.0])
    for s in range(10):
        _, idx, _ = bank.pick(query, 30, 3, torch.Generator().manual_seed(s), stand=stand)
        x = starts[idx, 0]
        assert x[0] > SIDE_MARGIN and x[1] < -SIDE_MARGIN, x
    assert int(bank.pick(query, 30, 1, stand=stand)[1][2]) == 20  # any side: the nearest
    near = starts.clone()
    near[20, 0] = SIDE_MARGIN / 2  # within the margin: on neither side
    on_neither = ReactionBank({30: latents}, starts={30: near})
    assert int(on_neither.pick(query[:1], 30, 1, stand=stand[:1])[1][0]) != 20
    left = ReactionBank({30: latents[:3]}, starts={30: starts[20:23]})  # nobody on the right
    assert left.pick(latents[:1], 30, 1, stand=torch.tensor([-1.0]))[1].tolist() == [0]
    # no side asked changes nothing, with a shortlist the bank cannot use (no captions)
    for s in range(5):
        g = (torch.Generator().manual_seed(s), torch.Generator().manual_seed(s))
        a = bank.pick(query, 30, 4, g[0], shortlist=2)[1]
        b = bank.pick(query, 30, 4, g[1], shortlist=2, stand=torch.zeros(3))[1]
        assert torch.equal(a, b)
    bank.save(tmp_path)
    torch.testing.assert_close(ReactionBank.load(tmp_path).starts[30], starts, atol=2e-3,
                               rtol=1e-3)  # fmt: skip
    ReactionBank({30: latents}, starts={30: starts[:, :1]}).save(tmp_path)
    with pytest.raises(UMFError, match="starts of 30 frames"):
        ReactionBank.load(tmp_path)


def test_avoid_keeps_a_reaction_off_where_someone_already_starts():
    """``pick(avoid=)``: only reactions starting at least ``SPOT`` from every point of the
    row's ``avoid`` compete, before the side; a row with none free keeps every candidate;
    an empty ``avoid`` changes nothing."""
    from umf.reaction_bank import SPOT

    g = torch.Generator().manual_seed(5)
    latents = torch.randn(6, P, R, generator=g)
    # left 0.9 (the nearest to the queries), left 1.0, right -0.9, ahead 2.5 ...
    starts = torch.tensor([[0.9, 0.0], [1.0, 0.2], [-0.9, 0.0], [0.0, 2.5], [2.0, 0.0],
                           [-1.0, 0.1]])  # fmt: skip
    bank = ReactionBank({30: latents}, starts={30: starts})
    query = latents[:1].expand(2, -1, -1) + 0.01
    assert bank.pick(query, 30, 1)[1].tolist() == [0, 0]
    person2 = torch.tensor([[[0.95, 0.1]], [[5.0, 5.0]]])  # row 2's person 2 is far away
    idx = bank.pick(query, 30, 1, avoid=person2)[1].tolist()
    assert idx[1] == 0
    assert float(torch.dist(starts[idx[0]], person2[0, 0])) >= SPOT
    # with the left asked, a free reaction on the left (2 m out) is taken
    assert bank.pick(query[:1], 30, 1, stand=torch.tensor([1.0]), avoid=person2[:1])[1] == 4
    # the right asked: only the right's reactions, both free
    right = bank.pick(query[:1], 30, 6, torch.Generator().manual_seed(0),
                      stand=torch.tensor([-1.0]), avoid=person2[:1])[1]  # fmt: skip
    assert int(right) in (2, 5)
    everywhere = torch.tensor([[[float(x), float(z)] for x, z in starts]])  # nobody free
    assert bank.pick(query[:1], 30, 1, avoid=everywhere)[1].tolist() == [0]
    empty = torch.zeros(2, 0, 2)
    assert bank.pick(query, 30, 1, avoid=empty)[1].tolist() == [0, 0]
    nobody = torch.full((2, 1, 2), float("nan"))  # NaN: nobody to keep off
    assert bank.pick(query, 30, 1, avoid=nobody)[1].tolist() == [0, 0]
    mixed = torch.cat([person2[:1], nobody[:1]])  # row 1 keeps off, row 2 has nobody
    got = bank.pick(query, 30, 1, avoid=mixed)[1].tolist()
    assert got[1] == 0 and float(torch.dist(starts[got[0]], person2[0, 0])) >= SPOT
