"""A couple started from a real take (``sflow.warm_take``, :mod:`umf.take_start`): the
P-Flow's finest-stage warm start, the bank's takes, their build and the pipeline's use."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from conftest import MODULE, FakeText, save_tiny_model
from umf.errors import UMFError
from umf.flows import (
    PyramidConfig,
    finest_warm_state,
    pyramid_training_sample,
    sample_finest_from,
    sample_time,
)
from umf.pipeline import UMFPipeline
from umf.reaction_bank import ReactionBank

pytestmark = pytest.mark.usefixtures("one_thread")
P, R = 4, 8


def test_the_warm_state_is_the_training_path_of_the_finest_stage():
    """The state a warm start enters is what training puts at that stage and time had the
    motion been the proposal: same noise, same t."""
    cfg = PyramidConfig(layout="1d", num_stages=2)
    g = torch.Generator().manual_seed(0)
    z = torch.randn(3, cfg.num_tokens, 5, generator=g)
    sample = pyramid_training_sample(z, cfg, stage=1, generator=torch.Generator().manual_seed(1))
    g1 = torch.Generator().manual_seed(1)  # the same draws: the times first, then the noise
    t_local = sample_time(3, generator=g1)
    eps = torch.randn(z.shape, generator=g1)
    torch.testing.assert_close(t_local, sample.t_local)
    t = float(t_local[0])
    state = finest_warm_state(z[:1], eps[:1], cfg.windows[-1], cfg.layout, t)
    torch.testing.assert_close(state, sample.x[:1])
    with pytest.raises(ValueError, match="0 < t < 1"):
        finest_warm_state(z, eps, cfg.windows[-1], cfg.layout, 1.0)
    with pytest.raises(ValueError, match="finest stage"):
        finest_warm_state(z, eps, cfg.windows[0], cfg.layout, 0.5)


@pytest.mark.parametrize(("t", "steps", "evals"), [(0.7, 5, 2), (0.5, 10, 5), (0.95, 5, 1)])
def test_a_field_pointing_at_the_proposal_lands_on_it(t, steps, evals):
    """With the field of the straight path to the proposal, the finest stage ends on it, in
    the remaining share of its steps (at least one)."""
    cfg = PyramidConfig(layout="1d", num_stages=2)
    w = cfg.windows[-1]
    proposal = torch.randn(2, cfg.num_tokens, 5, generator=torch.Generator().manual_seed(3))

    def field(x, t_global, stage):
        assert bool((stage == w.stage).all())
        local = (t_global - w.start) / (w.end - w.start)
        return (proposal - x) / (1.0 - local)[:, None, None]

    z, nfe = sample_finest_from(field, proposal, cfg, t, steps=steps)
    torch.testing.assert_close(z, proposal, atol=1e-5, rtol=1e-5)
    assert nfe == evals


@pytest.fixture(scope=MODULE)
def tiny(tmp_path_factory):
    return save_tiny_model(tmp_path_factory.mktemp("tiny") / "model")


def test_the_pflow_samples_again_from_a_proposal(tiny):
    pipe = UMFPipeline.from_pretrained(tiny, text_encoder=FakeText())
    text = pipe.text_encoder.encode(["two people dance", "two people dance"])
    uncond = pipe.text_encoder.encode([""] * 2)
    proposal = torch.randn(2, *pipe.vae.latent_shape, generator=torch.Generator().manual_seed(0))

    def run(t, seed=0):
        gen = [torch.Generator().manual_seed(seed + i) for i in range(2)]
        return pipe.pflow.sample(text, uncond, generator=gen, warm=proposal, warm_t=t)[0]

    torch.testing.assert_close(run(0.7), run(0.7))  # a function of the seed
    assert not torch.allclose(run(0.7), run(0.7, seed=5))
    far = (run(0.2) - proposal).norm(dim=(1, 2))
    near = (run(0.99) - proposal).norm(dim=(1, 2))
    assert bool((near < 0.2 * far).all())  # later on the path: nearer the proposal
    cold = pipe.pflow.sample(text, uncond, generator=[torch.Generator().manual_seed(0)] * 2)[0]
    assert cold.shape == proposal.shape and not torch.allclose(cold, run(0.7))


def _takes_bank(pipe, seed: int = 0) -> ReactionBank:
    """A bank with random reactions and two 'takes' of 3 and 2 crops, the first captioned
    twice ("two people dance salsa", "a couple dances"), the second once."""
    from umf.coverage import embed

    g = torch.Generator().manual_seed(seed)
    shape = pipe.vae.latent_shape
    texts = embed(pipe.text_encoder, ["two people dance salsa", "a couple dances",
                                      "two people shake hands"])  # fmt: skip
    nan = torch.full_like(texts[0], torch.nan)
    take_texts = torch.stack([torch.stack([texts[0], texts[1]])] * 3
                             + [torch.stack([texts[2], nan])] * 2)  # fmt: skip
    names = ["cmu-handshake/handshake-01", "cmu-salsa/salsa-01"]
    cut = torch.tensor([[1, 0], [1, 30], [1, 60], [0, 0], [0, 15]])  # (take row, first frame)
    return ReactionBank({30: torch.randn(10, *shape, generator=g)},
                        takes={30: torch.randn(5, 2, *shape, generator=g)},
                        take_texts={30: take_texts}, take_sources={30: cut},
                        take_names=names)  # fmt: skip


def test_takes_round_trip_and_a_prompt_draws_a_crop_of_its_nearest_take(tiny, tmp_path):
    from umf.coverage import embed

    pipe = UMFPipeline.from_pretrained(tiny, text_encoder=FakeText())
    bank = _takes_bank(pipe)
    bank.save(tmp_path)
    back = ReactionBank.load(tmp_path, pipe.vae.latent_shape)
    torch.testing.assert_close(back.takes[30], bank.takes[30], atol=2e-3, rtol=1e-3)
    assert torch.equal(back.take_texts[30].isnan(), bank.take_texts[30].isnan())
    torch.testing.assert_close(back.take_texts[30].nan_to_num(), bank.take_texts[30].nan_to_num(),
                               atol=2e-3, rtol=1e-3)  # fmt: skip
    prompts = embed(pipe.text_encoder, ["a couple dances", "two people shake hands"])
    seen = set()
    for s in range(20):
        gen = [torch.Generator().manual_seed(s), torch.Generator().manual_seed(100 + s)]
        length, idx, own = back.pick_take(31, prompts, gen)
        assert length == 30 and idx[0] in (0, 1, 2) and idx[1] in (3, 4) and bool(own.all())
        seen.add(int(idx[0]))
        alone = back.pick_take(31, prompts[:1], [torch.Generator().manual_seed(s)])
        assert int(alone[1][0]) == int(idx[0])  # a row's draw does not depend on its batch
    assert seen == {0, 1, 2}  # any crop of the take, not always the same
    assert ReactionBank({30: bank.latents[30]}).pick_take(30, prompts) is None
    assert back.take_names == bank.take_names
    assert back.take_source(30, torch.tensor([2, 4])) == [
        {"take": "cmu-salsa/salsa-01", "start_frame": 60, "frames": 30},
        {"take": "cmu-handshake/handshake-01", "start_frame": 15, "frames": 30},
    ]
    older = ReactionBank({30: bank.latents[30]}, takes=bank.takes, take_texts=bank.take_texts)
    (tmp_path / "older").mkdir()
    older.save(tmp_path / "older")  # a bank written before the sources
    assert ReactionBank.load(tmp_path / "older").take_source(30, torch.tensor([0])) == [None]


def test_a_take_caption_row_past_the_table_is_refused(tiny, tmp_path):
    from safetensors.torch import load_file, save_file

    pipe = UMFPipeline.from_pretrained(tiny, text_encoder=FakeText())
    path = _takes_bank(pipe).save(tmp_path)
    raw = load_file(str(path))
    raw["take_caption_30"][0, 0] = len(raw["captions"])
    save_file(raw, str(path))
    with pytest.raises(UMFError, match="corrupt reaction bank"):
        ReactionBank.load(tmp_path)
    raw["take_caption_30"][0, 0] = 0
    raw["take_source_30"][0, 0] = 2  # only two take names
    save_file(raw, str(path), metadata={"take_names": '["a", "b"]'})
    with pytest.raises(UMFError, match="sources of the takes"):
        ReactionBank.load(tmp_path)
    raw["take_source_30"][0, 0] = 0
    save_file(raw, str(path), metadata={"take_names": '"not a list"'})
    with pytest.raises(UMFError, match="corrupt reaction bank"):
        ReactionBank.load(tmp_path)
    raw["takes_30"] = raw["takes_30"][:, :1].contiguous()
    save_file(raw, str(path))
    with pytest.raises(UMFError, match="takes of 30 frames do not fit"):
        ReactionBank.load(tmp_path)


def test_touching_takes_are_cropped_whole_every_second(real_joints):
    """People 1 and 2 of a take whose people touch, every TAKE_STEP frames in person 1's
    frame; a take whose people stand apart, a take served twice, one too short: none."""
    from umf.data.clip import MotionClip
    from umf.representation import canonical_transform, canonicalize_features, joints_to_rot6d
    from umf.train.datasets import _clip_crop
    from umf.train.reactions import TAKE_STEP, touching_crops

    a = real_joints.float()[:100]

    def take(name, gap):
        b = a.clone()
        b[..., 0] += gap
        j = torch.stack([a, b])
        clip = MotionClip(name, "mocap", j.numpy(), [f"two people {name}", "a couple"])
        clip.rot6d = torch.stack([joints_to_rot6d(p) for p in j]).numpy()
        return ("clip", clip, canonical_transform(a))

    close, apart = take("hold hands", 0.45), take("stand apart", 2.0)

    class Served:
        def __init__(self) -> None:
            self.items = [close, close, apart, ("scene", {}, None)]

    crops, captions, cut = touching_crops(Served(), 30)
    starts = list(range(0, 99 - 30 + 1, TAKE_STEP))
    assert len(crops) == len(starts) == 3
    assert captions == [["a couple", "two people hold hands"]] * 3
    assert cut == [("hold hands", s) for s in starts]
    for crop, s in zip(crops, starts, strict=True):
        want = canonicalize_features(
            torch.as_tensor(_clip_crop(close[1], close[2], range(2), s, 30))
        )
        torch.testing.assert_close(crop, want.float())
        assert crop.shape == (2, 30, 262)
    assert touching_crops(Served(), 120) == ([], [], [])


def test_the_pipeline_starts_only_couples_worded_like_a_take_from_one(tiny, monkeypatch, tmp_path):
    """A prompt the vocabulary reads as a touching take's (its coverage's contact) has
    people 1 and 2 sampled again from one of the take's crops; near the end of the path
    they are that crop. Other prompts, and scenes sharing a batch with it, are untouched."""
    pipe = UMFPipeline.from_pretrained(tiny, text_encoder=FakeText())
    pipe.reactions = _takes_bank(pipe)
    pipe.config.sflow.warm_take = 0.999
    near = {"closest_m": 0.07, "pelvis_m": 0.29}
    monkeypatch.setattr(pipe, "coverage", lambda prompts: [
        {"score": 1.0, "known": True, "nearest": [], **({"contact": near} if "salsa" in p else {})}
        for p in prompts])  # fmt: skip
    salsa, walk = "two people dance salsa", "two people walk"
    both = pipe([salsa, walk], num_people=2, seconds=1.0, seed=3, fit=False)
    alone = pipe([walk], num_people=2, seconds=1.0, seed=3, fit=False)
    np.testing.assert_allclose(both[1].joints, alone[0].joints, atol=1e-4)  # batch: float order
    pipe.config.sflow.warm_take = 0.0
    plain = pipe([salsa, walk], num_people=2, seconds=1.0, seed=3, fit=False)
    assert np.array_equal(plain[1].joints, both[1].joints)
    assert not np.allclose(plain[0].joints, both[0].joints)
    pipe.config.sflow.warm_take = 0.999
    couple = pipe(salsa, num_people=2, seconds=1.0, seed=3, fit=False, separate=False)[0]
    crops = pipe.reactions.takes[30][:3]  # the salsa take's
    from umf.representation import features_to_joints

    with torch.no_grad():
        person_1 = features_to_joints(pipe.decode(crops[:, 0], 30)).numpy()
        person_2 = features_to_joints(pipe.decode(crops[:, 1], 30, reaction=True)).numpy()
    gap = [np.abs(couple.joints[0] - person_1[i]).max() for i in range(3)]
    assert min(gap) < 0.05 * np.abs(person_1).max()  # one of the take's crops, near enough
    crop = int(np.argmin(gap))  # ... and person 2 is the same crop's person 2
    gap_2 = [np.abs(couple.joints[1] - person_2[i]).max() for i in range(3)]
    assert int(np.argmin(gap_2)) == crop and min(gap_2) < 0.05 * np.abs(person_2).max()
    assert couple.meta["nfe"] > plain[0].meta["nfe"]
    again = pipe(salsa, num_people=2, seconds=1.0, seed=3, fit=False, separate=False)[0]
    assert np.array_equal(couple.joints, again.joints)
    take = couple.meta["take"]  # where the couple came from, in the scene and its NPZ
    assert take == {"take": "cmu-salsa/salsa-01", "start_frame": 30 * crop, "frames": 30,
                    "warm_take": 0.999}  # fmt: skip
    assert "take" not in both[1].meta
    path = tmp_path / "couple.npz"
    couple.save_npz(path)
    with np.load(path) as z:
        assert json.loads(str(z["take"])) == take


@pytest.mark.parametrize("value", ["1.0", "-0.1", "1.5"])
def test_a_warm_take_outside_0_to_1_is_refused(value):
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    with pytest.raises(UMFError, match="warm_take"):
        check_config_values(set_option(tiny_config(), f"sflow.warm_take={value}"))
    check_config_values(set_option(tiny_config(), "sflow.warm_take=0.7"))


def test_a_take_too_short_for_the_length_asked_lends_no_other(tiny):
    """A handshake stored at 30 frames only, asked for 60: the salsa crops stored there are
    nearer the prompt than nothing, but they are not its take."""
    from umf.coverage import embed

    pipe = UMFPipeline.from_pretrained(tiny, text_encoder=FakeText())
    bank = _takes_bank(pipe)
    salsa = bank.take_texts[30][:1]  # only the salsa take is long enough for 60 frames
    bank.takes[60], bank.take_texts[60] = bank.takes[30][:1], salsa
    prompts = embed(pipe.text_encoder, ["two people shake hands", "a couple dances"])
    length, _, own = bank.pick_take(60, prompts, [torch.Generator(), torch.Generator()])
    assert length == 60 and own.tolist() == [False, True]
    assert bool(bank.pick_take(30, prompts)[2].all())
