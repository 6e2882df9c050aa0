"""Per-person prompts through the pipeline, the files, re-rolls, the CLI and the JSON API
(tiny models: a random own-prompt projection, so an own prompt changes what it drives)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import MODULE, FakeText, save_tiny_model
from umf.errors import UMFError
from umf.pipeline import UMFPipeline

pytestmark = pytest.mark.usefixtures("one_thread")

SCENE = "two people stand facing each other"


@pytest.fixture(scope=MODULE)
def model(tmp_path_factory):
    return save_tiny_model(tmp_path_factory.mktemp("own") / "model", seed=2, person_prompts=True)


@pytest.fixture(scope=MODULE)
def pipe(model):
    return UMFPipeline.from_pretrained(model, text_encoder=FakeText())


@pytest.fixture(scope=MODULE)
def plain(tmp_path_factory):
    path = save_tiny_model(tmp_path_factory.mktemp("plain") / "model", seed=2)
    return path, UMFPipeline.from_pretrained(path, text_encoder=FakeText())


def _gen(pipe, own=None, people=2, seed=3):
    return pipe(SCENE, num_people=people, seconds=1.0, seed=seed, person_prompts=own,
                fit=False, separate=False)[0]  # fmt: skip


def test_each_prompt_drives_its_own_person(pipe):
    base = _gen(pipe)
    second = _gen(pipe, [None, "bows"])
    first = _gen(pipe, ["raises both hands"])
    # person 2's prompt leaves person 1 exactly as it was; person 1's changes person 1
    assert np.array_equal(second.joints[0], base.joints[0])
    assert np.abs(second.joints[1] - base.joints[1]).max() > 1e-3
    assert np.abs(first.joints[0] - base.joints[0]).max() > 1e-3
    swapped = _gen(pipe, ["bows", "raises both hands"])
    both = _gen(pipe, ["raises both hands", "bows"])
    assert not np.allclose(swapped.joints, both.joints)
    assert np.array_equal(_gen(pipe, ["raises both hands", "bows"]).joints, both.joints)
    assert both.meta["person_prompts"] == ["raises both hands", "bows"]
    assert second.meta["person_prompts"] == [None, "bows"]
    assert "person_prompts" not in base.meta
    three = _gen(pipe, ["waves"], people=3)
    assert three.meta["person_prompts"] == ["waves", None, None]


def test_bad_person_prompts_are_one_clear_error(pipe, plain):
    for own, needle in ((["a", "b", "c"], "3 person prompts for 2 people"),
                        ([" "], "the person prompt is empty"),
                        ([3], "every person prompt must be a string"),
                        ("bows", "must be a list"),
                        (["x" * 1001], "at most 1000 characters")):  # fmt: skip
        with pytest.raises(UMFError, match=needle):
            _gen(pipe, own)
    with pytest.raises(UMFError, match="not trained with per-person prompts"):
        _gen(plain[1], ["bows"])
    _gen(plain[1], [None, None])  # nothing asked of it: fine


def test_files_record_them_and_a_reroll_keeps_what_the_person_was_asked(pipe, tmp_path):
    from umf.data.motion_file import open_scene

    scene = pipe(SCENE, num_people=2, seconds=1.0, seed=3, person_prompts=[None, "bows"])[0]
    (path,) = scene.save(tmp_path / "scene", ["npz"])
    with np.load(path) as z:
        assert json.loads(str(z["person_prompts"])) == [None, "bows"]
    back = open_scene(path)
    assert back.meta["person_prompts"] == [None, "bows"]
    recorded = pipe.reroll(back, 2, seed=5)
    asked = pipe.reroll(back, 2, seed=5, person_prompt="bows")
    other = pipe.reroll(back, 2, seed=5, person_prompt="waves with the left hand")
    assert np.array_equal(recorded.joints, asked.joints)
    assert not np.allclose(other.joints[1], asked.joints[1])
    assert np.array_equal(other.joints[0], back.joints[0])  # everyone else bit for bit
    assert other.meta["person_prompts"] == [None, "waves with the left hand"]
    assert other.meta["rerolled"][-1]["person_prompt"] == "waves with the left hand"


def test_cli_person_options(model, plain, tmp_path, fake_text, capsys):
    from umf.cli.main import run

    out = tmp_path / "gen"
    with pytest.raises(SystemExit) as done:
        run(
            [
                "generate",
                SCENE,
                "--people",
                "2",
                "--seconds",
                "1",
                "--person",
                "raises both hands",
                "--person",
                "bows",
                "--format",
                "npz",
                "--out",
                str(out),
                "--model",
                str(model),
            ]
        )
    assert done.value.code in (0, None)
    (npz,) = out.glob("*.npz")
    with np.load(npz) as z:
        assert json.loads(str(z["person_prompts"])) == ["raises both hands", "bows"]
    capsys.readouterr()
    for args, needle in (([str(model), "--person", "a", "--person", "b", "--person", "c"],
                          "3 person prompts for 2 people"),
                         ([str(plain[0]), "--person", "bows"],
                          "not trained with per-person prompts")):  # fmt: skip
        bad = tmp_path / "bad"
        with pytest.raises(SystemExit) as exit_:
            run(["generate", SCENE, "--people", "2", "--seconds", "1", "--format", "npz",
                 "--out", str(bad), "--model", *args])  # fmt: skip
        err = capsys.readouterr().err
        assert exit_.value.code == 1 and needle in err and err.count("\n") == 1, err
        assert not list(bad.glob("*.npz"))
    # umf react: the first --person is person 2 (person 1 is the given motion)
    react = tmp_path / "react"
    actor = str(Path(__file__).parent / "clips" / "dataset-2_raise-up-both-hands_normal_001.bvh")
    with pytest.raises(SystemExit) as done:
        run(["react", SCENE, "--actor", actor, "--people", "2", "--person", "bows",
             "--format", "npz", "--out", str(react), "--model", str(model)])  # fmt: skip
    assert done.value.code in (0, None)
    with np.load(next(react.glob("*.npz"))) as z:
        assert json.loads(str(z["person_prompts"])) == [None, "bows"]
    with pytest.raises(SystemExit) as exit_:
        run(["react", SCENE, "--actor", actor, "--people", "2", "--person", "a",
             "--person", "b", "--out", str(tmp_path / "r2"), "--model", str(model)])  # fmt: skip
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and "2 --person prompts for 1 added person" in err, err
    # umf reroll --person-prompt
    rr = tmp_path / "rr"
    with pytest.raises(SystemExit) as done:
        run(["reroll", str(npz), "--person", "2", "--person-prompt", "waves", "--format", "npz",
             "--out", str(rr), "--model", str(model)])  # fmt: skip
    assert done.value.code in (0, None)
    with np.load(next(rr.glob("*.npz"))) as z:
        assert json.loads(str(z["person_prompts"])) == ["raises both hands", "waves"]


def test_json_api_fields():
    from umf.serve.validate import RequestError, parse_generate, parse_reroll

    req = parse_generate({"prompt": SCENE, "people": 3, "person_prompts": ["bows", None, ""]})
    assert req.person_prompts == ("bows", None, None)
    assert parse_generate({"prompt": SCENE}).person_prompts == ()
    for body, needle in (({"person_prompts": "bows"}, "must be a list"),
                         ({"person_prompts": ["a", "b", "c"]}, "3 entries for 2 people"),
                         ({"person_prompts": [1]}, "entry 1 must be a string"),
                         ({"person_prompts": ["x" * 501]}, "longer than 500")):  # fmt: skip
        with pytest.raises(RequestError, match=needle):
            parse_generate({"prompt": SCENE, **body})
    again = parse_reroll({"scene": "s1", "person": 2, "person_prompt": " bows "})
    assert again.person_prompt == "bows"
    with pytest.raises(RequestError, match="must be a string"):
        parse_reroll({"scene": "s1", "person": 2, "person_prompt": 5})


def test_top1_is_own_prompt_nearest():
    from umf.eval.person_matching import top1

    texts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    motion = np.array([[0.1, 0.0], [0.0, 0.9], [0.0, 0.8]])  # person 2 looks like prompt 3
    assert top1(motion, texts) == [True, False, True]


def test_person_items_are_scenes_of_different_actions_with_their_clips_wordings(tmp_path):
    from conftest import prepare_fixture_corpus
    from umf.data.corpus import Corpus
    from umf.eval.person_matching import person_items
    from umf.train.datasets import mirror_caption

    # the fixture's test clips are walks only: its train split has other actions
    corpus = Corpus.load(prepare_fixture_corpus(tmp_path / "c", train_scenes=40, val_scenes=2,
                                                test_scenes=2, test_groups=2))  # fmt: skip
    captions = {c.id: c.captions[0] for c in corpus.clips}
    items = person_items(corpus, "train")
    differ = [r for r in corpus.scenes["train"]
              if len({p["content"] for p in r["people"]}) == len(r["people"])]  # fmt: skip
    assert items and len(items) == len(differ)
    for (caption, own), recipe in zip(items, differ, strict=True):
        assert caption == recipe["captions"][0]
        for p, o in zip(recipe["people"], own, strict=True):
            want = captions[p["clip"]]
            assert o == (mirror_caption(want) if p.get("mirrored") else want)
    same = [r for r in corpus.scenes["train"] if len({p["content"] for p in r["people"]}) == 1]
    assert same and len(items) == len(corpus.scenes["train"]) - len(same)


def test_person_matching_scores_every_person_and_the_report_shows_it(pipe):
    from test_eval_evaluator import tiny
    from umf.eval.markdown import person_markdown
    from umf.eval.person_matching import person_matching

    ev = tiny("single")
    items = [(SCENE, ["raises both hands", "bows"]), (SCENE, ["waves", "kicks", "calls"])]
    out = person_matching(pipe, ev, items, seconds=1.0)
    assert out["scenes"] == 2 and out["people"] == 5
    assert 0.0 <= out["top1"] <= 1.0 and out["chance"] == pytest.approx((2 / 2 + 3 / 3) / 5)
    text = person_markdown({"tiny": out})
    assert "Per-person text matching" in text and "| tiny | 2 | 5 |" in text


def test_training_stages_take_each_flows_own_person():
    """P-Flow trains on person 1's own caption, S-Flow on the reacting person's."""
    from test_hardening import _fresh, _latent_batch, _stages
    from umf.train.stages import own_captions

    pipe = _fresh("cpu")
    batch = _latent_batch(pipe, "cpu")
    batch["person_captions"] = [[f"s{i}p{k}" for k in range(3)] for i in range(4)]
    assert own_captions(batch, [0, 2, 1, 0]) == ["s0p0", "s1p2", "s2p1", "s3p0"]
    assert own_captions({"person_captions": [[], ["x"]]}, [1, 0]) == ["", "x"]
    assert own_captions({"captions": ["a"]}, torch.tensor([1])) == [""]
    pstage, sstage = _stages(pipe)
    assert pstage._inputs(batch)[3] == [f"s{i}p0" for i in range(4)]
    for _ in range(5):  # a random reacting person each time: its own caption comes along
        lat, prev_mask, w, _, own = sstage._inputs(batch)
        for i in range(4):
            k = int(prev_mask[i].sum())  # the reacting person follows the previous ones
            assert torch.equal(w[i], lat[i, k]) and own[i] == f"s{i}p{k}"


def test_a_latent_bank_keeps_the_own_captions():
    from umf.train.latents import LatentBankDataset

    bank = {"z": torch.zeros(2, 2, 4, 8), "people_mask": torch.ones(2, 2, dtype=torch.bool),
            "dataset": torch.ones(2, dtype=torch.long), "captions": ["a", "b"],
            "person_captions": [["a1", "a2"], ["b1", ""]]}  # fmt: skip
    full, first = LatentBankDataset(bank), LatentBankDataset(bank, first_person_only=True)
    assert full.collate([full[0], full[1]])["person_captions"] == [["a1", "a2"], ["b1", ""]]
    assert first.collate([first[0], first[1]])["person_captions"] == [["a1"], ["b1"]]
    del bank["person_captions"]  # a bank of a build before them: none
    assert LatentBankDataset(bank)[0]["person_captions"] == []


def test_a_fine_tune_grows_the_projection_and_refuses_a_flow_it_would_not_train(tmp_path):
    from umf.checkpoint import checked_weights
    from umf.config import UMFConfig
    from umf.models.pflow import PFlow
    from umf.train.growth import grows
    from umf.train.run import Launch, finetune

    old = save_tiny_model(tmp_path / "old", seed=1)
    cfg = UMFConfig.from_dict(json.loads((old / "config.json").read_text()))
    cfg.pflow.denoiser.person_text = True
    grown = PFlow(cfg.pflow, 4, 8, FakeText.dim)
    weights = checked_weights(old, "pflow", grown, may_lack=grows)
    assert not any("person_proj" in k for k in weights)
    with pytest.raises(UMFError, match="missing"):
        checked_weights(old, "pflow", grown)
    with pytest.raises(UMFError, match="needs sflow in --stages"):
        finetune(old, tmp_path / "corpus", tmp_path / "run",
                 ["pflow.denoiser.person_text=true", "sflow.denoiser.person_text=true"],
                 Launch(), stages=["pflow"], log=lambda m: None)  # fmt: skip
    with pytest.raises(UMFError, match="person_head=true needs sflow in --stages"):
        finetune(old, tmp_path / "corpus", tmp_path / "run2",
                 ["pflow.denoiser.person_text=true", "sflow.denoiser.person_text=true",
                  "sflow.denoiser.person_head=true"],
                 Launch(), stages=["pflow", "vae"], log=lambda m: None)  # fmt: skip


def test_cli_dash_skips_a_person(model, tmp_path, fake_text):
    from umf.cli.generate import person_list
    from umf.cli.main import run

    assert person_list(["-", "bows"]) == [None, "bows"]
    assert person_list(["", " - "]) is None and person_list([]) is None
    out = tmp_path / "gen"
    with pytest.raises(SystemExit) as done:
        run(["generate", SCENE, "--people", "2", "--seconds", "1", "--person", "-", "--person",
             "bows", "--format", "npz", "--out", str(out), "--model", str(model)])  # fmt: skip
    assert done.value.code in (0, None)
    with np.load(next(out.glob("*.npz"))) as z:
        assert json.loads(str(z["person_prompts"])) == [None, "bows"]


def test_relation_repeats_must_name_relations():
    from umf.config import set_option, small_config
    from umf.model_checks import check_config_values

    cfg = set_option(small_config(), "train_sflow.relation_repeats=[stand_facing=8]")
    check_config_values(cfg)
    bad = set_option(small_config(), "train_sflow.relation_repeats=[stand_facng=8]")
    with pytest.raises(UMFError, match="no relation 'stand_facng'"):
        check_config_values(bad)


def test_a_recorded_prompt_is_left_aside_by_a_model_without_them(pipe, plain, tmp_path):
    scene = pipe(SCENE, num_people=2, seconds=1.0, seed=3, person_prompts=[None, "bows"])[0]
    again = plain[1].reroll(scene, 2, seed=5)  # no error: the recorded prompt is not asked
    assert np.array_equal(again.joints[0], scene.joints[0])
    with pytest.raises(UMFError, match="not trained with per-person prompts"):
        plain[1].reroll(scene, 2, seed=5, person_prompt="waves")
    new = pipe.reroll(scene, 2, seed=5, person_prompt="waves")
    assert new.meta["person_prompts"] == [None, "waves"]
    assert new.meta["person_coverage"] == [None, None]  # tiny models carry no vocabulary
