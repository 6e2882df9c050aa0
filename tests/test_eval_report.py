"""`umf eval --quick` end to end on a tiny setup, and its one-line errors.

The setup is real data with untrained weights: a corpus prepared from the bundled Bandai
clips, a tiny randomly initialised UMF (plus a reaction-only variant) and a tiny randomly
initialised evaluator, all saved in the formats `umf train` writes. Numbers of untrained
models mean nothing; the test checks the report's structure and the real-data references.
"""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import TINY_MODEL, prepare_fixture_corpus
from umf.checkpoint import save_checkpoint
from umf.cli.main import app, run
from umf.config import EvaluatorConfig, set_option, small_config
from umf.data.corpus import Corpus
from umf.errors import UMFError
from umf.eval import markdown as MD
from umf.eval import plan as P
from umf.eval import report as R
from umf.eval.evaluator import MotionTextEvaluator, evaluator_config_dict
from umf.pipeline import UMFPipeline

TINY_EVALUATOR = EvaluatorConfig(
    d_model=16, num_layers=1, num_heads=2, ff_dim=32, dropout=0.0, embed_dim=8, text_width=16,
    text_layers=1, text_heads=2, text_ff_dim=32, text_max_length=32, frames_per_token=4,
)  # fmt: skip


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


def save_tiny_model(path, normalizer, *options: str):
    """A randomly initialised tiny UMF in the model-directory format."""
    cfg = small_config()
    for o in (*TINY_MODEL, *options):
        cfg = set_option(cfg, o)
    torch.manual_seed(0)
    pipe = UMFPipeline.build(cfg)
    modules = {"vae": pipe.vae, "pflow": pipe.pflow, "sflow": pipe.sflow}
    return save_checkpoint(path, modules, config=cfg.to_dict(), normalizer=normalizer)


def save_tiny_evaluators(run_dir, normalizer):
    """Random evaluators of both kinds where `umf train evaluator` puts them."""
    for kind in ("interaction", "single"):
        torch.manual_seed(1)
        ev = MotionTextEvaluator(TINY_EVALUATOR, kind, text_dim=384)
        ev.set_normalizer(normalizer)
        save_checkpoint(run_dir / "evaluator" / kind / "best", {"evaluator": ev},
                        config=evaluator_config_dict(ev), normalizer=normalizer)  # fmt: skip


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval-report")
    prepare_fixture_corpus(root / "corpus", train_scenes=4, val_scenes=2, test_scenes=8,
                           test_groups=3)  # fmt: skip
    norm = Corpus.load(root / "corpus").normalizer
    save_tiny_model(root / "tiny" / "model", norm)
    save_tiny_model(root / "reaction", norm, "sflow.reaction_only=true")
    save_tiny_evaluators(root / "evrun", norm)
    return root


def test_quick_eval_end_to_end(setup):
    root, out = setup, setup / "results"
    args = ["eval", "--checkpoint", str(root / "tiny" / "model"), "--evaluator",
            str(root / "evrun"), "--corpus", str(root / "corpus"), "--out", str(out), "--quick",
            "--variant", f"reaction-only={root / 'reaction'}", "--no-progress",
            "--device", "cpu"]  # fmt: skip
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    for name in ("report.md", "metrics.json", "accumulation.png", "accumulation.csv",
                 "relations.png", "examples.png"):  # fmt: skip
        assert (out / name).stat().st_size > 0, name
    m = json.loads((out / "metrics.json").read_text())
    assert [s["name"] for s in m["sources"]] == ["real", "tiny", "reaction-only"]
    proto = m["protocol"]["interaction"]
    assert proto["items"] == proto["group"] == 8  # fewer than 96 test items: groups of 8
    for src in ("real", "tiny", "reaction-only"):
        got = proto["results"][src]
        assert {"fid", "r_precision_top1", "r_precision_top3", "mm_dist", "diversity"} <= set(got)
        assert len(got["fid"]) == 2  # mean, CI
    assert "multimodality" in proto["results"]["tiny"]
    assert "single" not in m["protocol"]  # one single test clip: skipped, and said so
    assert any("single-person protocol skipped" in n for n in m["notes"])
    for name in ("pairs", "groups"):
        assert m["relations"][name]["real"]["scene_accuracy"] == 1.0
        assert 0.0 <= m["relations"][name]["tiny"]["scene_accuracy"] <= 1.0
        # the main model is also scored as users receive it; variants only raw
        assert set(m["physics"][name]) == {"real", "tiny", "reaction-only", "tiny, delivered"}
        assert "tiny, delivered" in m["relations"][name]
        assert m["physics"][name]["real"]["penetration_cm"][0] == 0.0  # composer keeps apart
    # groups are also read in any order of the people their captions leave open; pairs not
    loose = m["relations"]["groups"]["tiny"]["any_order"]
    assert loose["scene_accuracy"] >= m["relations"]["groups"]["tiny"]["scene_accuracy"]
    assert set(loose["by_relation"]) == set(m["relations"]["groups"]["tiny"]["by_relation"])
    assert 0.0 <= loose["scene_accuracy_ci"] < 1.0
    assert "any_order" not in m["relations"]["pairs"]["tiny"]
    assert m["relations"]["all"]["real"]["num_scenes"] == 8 + 3
    assert {r["variant"] for r in m["accumulation"]} == {"tiny", "reaction-only"}
    assert {r["N"] for r in m["accumulation"]} == {2, 3, 4}
    speed = m["speed"]["tiny"]
    assert speed["nfe"] == 6 + 3  # P-Flow 4 + 2, S-Flow 3
    assert speed["flops"] > speed["text_encoder_flops"] > 0
    text = (out / "report.md").read_text()
    assert text.startswith("# UMF evaluation: tiny")
    assert "umf eval --checkpoint" in text and "--quick" in text
    assert "groups of 8 instead of 96" in text and "![examples](examples.png)" in text
    assert "inter-person penetration (cm) ↓, groups, delivered" in text
    assert "people the caption leaves open in any order" in text
    assert set(m["motion"]) == {"tiny", "tiny, delivered", "reaction-only"}
    assert m["meta"]["split"] == "test" and "single-person test clips" in text


def test_val_split_chooses_without_the_test_set(setup):
    """--split val scores the val pairs (groups exist only in test) and says so."""
    root, out = setup, setup / "val"
    args = ["eval", "--checkpoint", str(root / "tiny" / "model"), "--evaluator",
            str(root / "evrun"), "--corpus", str(root / "corpus"), "--out", str(out), "--quick",
            "--split", "val", "--mm-prompts", "0", "--no-progress", "--device", "cpu"]  # fmt: skip
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["meta"]["split"] == "val" and m["plan"]["split"] == "val"
    corpus = Corpus.load(root / "corpus")
    assert m["relations"]["pairs"]["real"]["num_scenes"] == len(corpus.scenes["val"]) == 2
    assert "groups" not in m["relations"] and "groups" not in m["physics"]
    assert any("no val_groups scenes" in n for n in m["notes"])
    text = (out / "report.md").read_text()
    assert "**val split**" in text and "--split val" in text and "val pairs" in text
    assert m["reconstruction"] and "single-person val clips" in text
    with pytest.raises(UMFError, match="--split"):
        P.make_plan(split="train")


def test_quick_eval_of_the_bundled_model(setup):
    """The smoke run: the shipped model scored by the shipped evaluators (the default)."""
    from umf.pipeline import default_model_dir

    out = setup / "bundled"
    args = ["eval", "--checkpoint", str(default_model_dir()), "--corpus", str(setup / "corpus"),
            "--out", str(out), "--quick", "--no-progress", "--device", "cpu"]  # fmt: skip
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    m = json.loads((out / "metrics.json").read_text())
    names = [s["name"] for s in m["sources"]]
    assert names[0] == "real" and names[1].startswith("umf-small-bandai")
    top3 = m["protocol"]["interaction"]["results"]["real"]["r_precision_top3"][0]
    assert 0.0 < top3 <= 1.0
    assert m["relations"]["pairs"]["real"]["scene_accuracy"] == 1.0
    assert (out / "report.md").read_text().startswith("# UMF evaluation: umf-small-bandai")


def test_plan_and_helpers():
    quick = P.make_plan(quick=True, mm_samples=3)
    assert (quick.replications, quick.mm_prompts, quick.mm_pairs) == (2, 8, 3)
    assert P.make_plan().replications == 20 and P.make_plan().accumulation_sizes[-1] == 8
    assert P.length_batches([30, 40, 30, 30, 40], 2) == [[0, 2], [3], [1, 4]]
    assert P.clamp_frames([3, 50, 400], 300) == [15, 50, 300]
    assert P.bucket_frames([16, 30, 31, 290], 15, 300) == [30, 30, 45, 300]
    assert P.bucket_frames([16, 31], 1, 300) == [16, 31]
    assert P.batch_seed(0, 1) == P.batch_seed(0, 1) != P.batch_seed(0, 2)
    assert P.parse_variant("no-pyramid=runs/a/model") == ("no-pyramid", R.Path("runs/a/model"), {})
    assert P.parse_variant("25-25=m:pflow_steps=25,25:sflow_steps=4:guidance=2")[2] == {
        "pflow_steps": (25, 25),
        "sflow_steps": 4,
        "guidance": 2.0,
    }
    for bad in ("x", "=m", "a=m:steps=3", "a=m:sflow_steps=many", "a=m:pflow_steps"):
        with pytest.raises(UMFError):
            P.parse_variant(bad)
    assert P.model_label(R.Path("runs/small/model")) == "small"
    assert MD.fmt(0.5, 0.01) == "0.500 ± 0.010" and MD.fmt(float("nan")) == "—"
    assert R.jsonable({"a": (np.float32(1.5), float("inf"))}) == {"a": [1.5, None]}


def test_variants_share_the_first_person_only_when_it_is_the_same(setup, monkeypatch):
    plan, tiny = P.make_plan(quick=True), setup / "tiny" / "model"
    variants = [
        ("s-steps", tiny, {"sflow_steps": 2}),
        ("p-steps", tiny, {"pflow_steps": (2, 1)}),
        ("reaction-only", setup / "reaction"),
    ]  # same seed: same VAE and P-Flow
    cs = R.load_contenders(tiny, variants, "cpu", plan, progress=False)
    assert cs[0].pipe is cs[1].pipe is cs[2].pipe and cs[3].pipe is not cs[0].pipe
    keys = [R.person_one_key(c) for c in cs]
    assert keys[0] == keys[1] == keys[3] != keys[2]
    assert cs[1].features_fn(2)(["two people bow"], [30], 0)[0].shape == (2, 30, 262)

    calls = []  # the single-person protocol scores each distinct first person once

    def score(evaluator, items, generate, cfg, log):
        calls.append(generate)
        return {"real": {"fid": (0.0, 0.0)}, "generated": {"fid": (float(len(calls)), 0.0)}}

    class Item:
        num_frames = 30

    monkeypatch.setattr(R, "corpus_items", lambda corpus, split, kind: [Item()] * 4)
    monkeypatch.setattr(R, "score_protocol", score)
    ev = type("Ev", (), {"cfg": type("C", (), {"max_frames": 300})()})()
    notes: list[str] = []
    out = R.protocol_section(ev, None, "single", cs, plan, notes, lambda s: None)
    assert len(calls) == 2
    assert out["results"]["s-steps"] == out["results"]["reaction-only"] == out["results"]["tiny"]
    assert out["results"]["p-steps"] != out["results"]["tiny"]
    assert sum("shares its scores" in n for n in notes) == 2
    calls.clear()
    R.protocol_section(ev, None, "interaction", cs, plan, [], lambda s: None)
    assert len(calls) == 4  # two people: every contender is scored


def test_a_model_copy_with_other_guidance_is_another_first_person(setup, tmp_path):
    """Sampling defaults live in the model's config too: a copy whose P-Flow guidance
    differs makes other single-person scenes; one whose S-Flow guidance differs does not."""
    tiny = setup / "tiny" / "model"
    for name, stage in (("p", "pflow"), ("s", "sflow")):
        shutil.copytree(tiny, tmp_path / name)
        cfg = json.loads((tiny / "config.json").read_text())
        cfg[stage]["guidance"] = 1.5
        (tmp_path / name / "config.json").write_text(json.dumps(cfg))
    plan = P.make_plan(quick=True)
    cs = R.load_contenders(tiny, [("p", tmp_path / "p"), ("s", tmp_path / "s")], "cpu", plan,
                           progress=False)  # fmt: skip
    keys = [R.person_one_key(c) for c in cs]
    assert keys[0] == keys[2] != keys[1]
    # and the scenes themselves: the key is a shortcut, the scenes are what it stands for
    one = [c.features_fn(1)(["a person waves"], [30], 0)[0] for c in cs]
    assert np.array_equal(one[0], one[2]) and not np.allclose(one[0], one[1], atol=1e-4)


def test_generation_keeps_each_length(setup):
    plan = P.make_plan(quick=True)  # lengths bucketed by 15 frames, then cut back
    (c,) = R.load_contenders(setup / "tiny" / "model", [], "cpu", plan, progress=False)
    feats = c.features_fn(2)(
        ["a person waves", "two people bow", "a person runs"], [20, 37, 500], 0
    )
    assert [f.shape for f in feats] == [(2, 20, 262), (2, 37, 262), (2, 120, 262)]
    assert c.timing[2][1] == 3


def _umf(monkeypatch, capsys, *args: str) -> tuple[int, str]:
    """The console entry point in-process: (exit code, stderr)."""
    monkeypatch.setattr(sys, "argv", ["umf", *args])
    with pytest.raises(SystemExit) as exc:
        run()
    return int(exc.value.code or 0), capsys.readouterr().err


def test_bad_inputs_are_one_line(setup, tmp_path, monkeypatch, capsys):
    root = setup
    model, corpus = str(root / "tiny" / "model"), str(root / "corpus")
    monkeypatch.chdir(tmp_path)  # no out/corpus here
    code, err = _umf(monkeypatch, capsys, "eval", "--checkpoint", model)
    assert code == 1 and "make corpus" in err and err.count("\n") == 1
    code, err = _umf(monkeypatch, capsys, "eval", "--checkpoint", str(tmp_path / "nope"),
                     "--corpus", corpus)  # fmt: skip
    assert code == 1 and "model not found" in err and err.count("\n") == 1
    code, err = _umf(monkeypatch, capsys, "eval", "--checkpoint", model, "--variant", "x")
    assert code == 1 and "NAME=MODEL_DIR" in err
    bad = tmp_path / "bad-evaluator" / "interaction"
    bad.mkdir(parents=True)
    (bad / "format.json").write_text("{not json")
    out = tmp_path / "report"
    code, err = _umf(monkeypatch, capsys, "eval", "--checkpoint", model, "--corpus", corpus,
                     "--evaluator", str(bad.parent), "--out", str(out), "--quick")  # fmt: skip
    assert code == 1 and err.startswith("umf: error:") and err.count("\n") == 1
    assert not out.exists()  # nothing half-written


def test_evaluator_locations(setup, tmp_path):
    ev = setup / "evrun" / "evaluator"
    assert set(R.load_evaluators(setup / "evrun", None, "cpu")) == {"interaction", "single"}
    assert set(R.load_evaluators(ev, None, "cpu")) == {"interaction", "single"}  # bundled layout
    assert set(R.load_evaluators(ev / "interaction", None, "cpu")) == {"interaction"}
    run = tmp_path / "run" / "evaluator"
    shutil.copytree(ev / "interaction", run / "interaction")
    (run / "single").mkdir()  # its training has not written a checkpoint yet
    assert set(R.load_evaluators(tmp_path / "run", None, "cpu")) == {"interaction"}
    with pytest.raises(UMFError, match="interaction"):
        R.load_evaluators(ev / "single", None, "cpu")
    with pytest.raises(UMFError, match="not found"):
        R.load_evaluators(tmp_path / "nowhere", None, "cpu")


def test_kinds_whose_reading_changes_get_an_any_order_row():
    """A kind whose accuracy read in any order differs from the strict one for some source
    gets a "kind: K, any order" row (a source without that reading shows "—"); a kind the
    order does not change gets none."""
    from umf.eval.markdown import relations_markdown

    def acc(side: float, loose_side: float | None) -> dict:
        out = {"scene_accuracy": 0.5, "scene_accuracy_ci": 0.1, "check_accuracy": 0.8,
               "kind_accuracy": 0.8, "num_scenes": 4, "num_checks": 8, "by_relation": {},
               "by_kind": {"side": {"accuracy": side, "count": 4},
                           "no_contact": {"accuracy": 0.75, "count": 4}}}  # fmt: skip
        if loose_side is not None:
            kinds = {"side": {"accuracy": loose_side, "count": 4},
                     "no_contact": {"accuracy": 0.75, "count": 4}}  # fmt: skip
            out["any_order"] = {"scene_accuracy": 0.75, "by_relation": {}, "by_kind": kinds}
        return out

    text = relations_markdown({"groups": {"m": acc(0.5, 1.0), "ablation": acc(0.25, None)}})
    assert "| kind: side, any order | 1.000 | — |" in text
    assert "no_contact, any order" not in text
    text = relations_markdown({"groups": {"m": acc(0.5, 0.5)}})
    assert "side, any order" not in text


def test_single_protocol_loads_both_models_and_says_why_it_cannot_score(setup, tmp_path):
    """research/single_protocol.py: a model and a variant, the fixture's evaluator, and the
    protocol's own reason where a split holds too few single-person items (the fixture's
    test split has one), as one line, before any JSON is written."""
    from conftest import load_script

    out = tmp_path / "single.json"
    with pytest.raises(SystemExit, match="single-person protocol skipped: test items 1"):
        load_script("single_protocol").main([
            str(setup / "tiny" / "model"), str(setup / "reaction"), "--corpus",
            str(setup / "corpus"), "--split", "test", "--replications", "1", "--evaluator",
            str(setup / "evrun"), "--json", str(out)])  # fmt: skip
    assert not out.exists()
