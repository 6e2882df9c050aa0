"""scripts/reproduce_bundled.py trains the bundled model again: its stages, applied in the
order their --init chain inherits configs, must give the shipped config.json."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

from umf.config import UMFConfig, family_config, set_option

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "reproduce_bundled.py"


def _script():
    spec = importlib.util.spec_from_file_location("reproduce_bundled", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_stages_rebuild_the_shipped_config(tmp_path):
    rb = _script()
    stages = {st.name: st.commands for st in rb.stages(tmp_path, Path("out/corpus"))}
    # each stage's model is the next one's --init (or source), so configs carry over; the
    # P-Flow fine-tune "hg" is not in the chain of configs: the decoder stage starts from the
    # S-Flow's model and takes hg's P-Flow as its export --base (as the release did)
    chain = [
        "gpu",
        "sampling",
        "rn0.5",
        "rn0.5b",
        "rn0.25c",
        "rn0.125d",
        "dec",
        "mix",
        "teach",
        "reteach",
        "rebalance",
        "settle",
        "pace",
        "steps",
        "person",
        "person2",
        "place",
        "gait",
        "leader",
        "jump",
        "name",
    ]
    cfg = family_config("small")
    for name in chain:
        command = stages[name][0]
        if "finetune" in command:  # umf train finetune applies its stages' defaults first
            from umf.train.run import FINETUNE

            trained = ["vae", "pflow", "sflow"]
            if "--stages" in command:
                trained = command[command.index("--stages") + 1].split(",")
            for o in FINETUNE:
                if o.split(".")[0].removeprefix("train_") in trained:
                    cfg = set_option(cfg, o)
        for i, arg in enumerate(command):
            if arg == "--set":
                cfg = set_option(cfg, command[i + 1])
    got = json.loads(json.dumps(cfg.to_dict()))  # tuples as lists, as in the file
    shipped = json.loads((ROOT / "src" / "umf" / "assets" / "model" / "config.json").read_text())
    # read as umf reads it: options added since it was written take their defaults
    want = json.loads(json.dumps(UMFConfig.from_dict(shipped).to_dict()))
    # training fills text.respell from the corpus
    for c in (got, want):
        c["text"].pop("respell")
    assert got == want
    # and the chain is wired: each fine-tune starts from, and exports over, the model the
    # documented step started from; the last stage names the caption-mixing model
    models = tmp_path / "models"
    wiring = {"rn0.5": ("sampling", "sampling"), "rn0.5b": ("rn0.5", "rn0.5"),
              "rn0.25c": ("rn0.5b", "rn0.5b"), "rn0.125d": ("rn0.25c", "rn0.25c"),
              "hg": ("rn0.125d", "rn0.125d"), "dec": ("rn0.125d", "hg"),
              "mix": ("dec", "dec")}  # fmt: skip
    for name, (init, base) in wiring.items():
        train, export = stages[name]
        assert train[train.index("--init") + 1] == str(models / init), name
        assert export[export.index("--base") + 1] == str(models / base), name
        assert export[export.index("--out") + 1] == str(models / name), name
    assert stages["sampling"][0][2:4] == [str(models / "gpu"), str(models / "sampling")]
    # the model_variant stages, which refuse an existing destination, replace one left by a kill
    writes = {st.name: st.writes for st in rb.stages(tmp_path, Path("out/corpus")) if st.writes}
    assert writes == {"sampling": models / "sampling", "steps": models / "steps",
                      "name": tmp_path / "model"}  # fmt: skip
    teach = stages["teach"][0]
    assert teach[teach.index("--from") + 1] == str(models / "mix")
    run = tmp_path / "runs" / "teach"
    assert teach[teach.index("--out") + 1] == str(run)
    reteach = stages["reteach"][0]
    assert reteach[reteach.index("--from") + 1] == str(run / "model")
    again = tmp_path / "runs" / "reteach"
    assert reteach[reteach.index("--out") + 1] == str(again)
    rebalance = stages["rebalance"][0]
    assert rebalance[rebalance.index("--from") + 1] == str(again / "model")
    assert rebalance[rebalance.index("--stages") + 1] == "pflow"
    balanced = tmp_path / "runs" / "rebalance"
    assert rebalance[rebalance.index("--out") + 1] == str(balanced)
    settle = stages["settle"][0]
    assert settle[settle.index("--from") + 1] == str(balanced / "model")
    assert settle[settle.index("--stages") + 1] == "pflow"
    assert "train_pflow.settle=true" in _sets(settle)
    assert "train_pflow.settle=true" not in _sets(rebalance)
    last = tmp_path / "runs" / "settle"
    assert settle[settle.index("--out") + 1] == str(last)
    pace = stages["pace"][0]
    assert pace[pace.index("--from") + 1] == str(last / "model")
    assert pace[pace.index("--stages") + 1] == "sflow"
    paced = tmp_path / "runs" / "pace"
    assert pace[pace.index("--out") + 1] == str(paced)
    assert stages["steps"][0][2:4] == [str(paced / "model"), str(models / "steps")]
    person = stages["person"][0]
    assert person[person.index("--from") + 1] == str(models / "steps")
    assert person[person.index("--stages") + 1] == "pflow,sflow"
    person2 = stages["person2"][0]
    assert person2[person2.index("--from") + 1] == str(tmp_path / "runs" / "person" / "model")
    assert "train_sflow.relation_repeats=[stand_facing=8]" in _sets(person2)
    place = stages["place"][0]
    assert place[place.index("--from") + 1] == str(tmp_path / "runs" / "person2" / "model")
    assert place[place.index("--stages") + 1] == "sflow"
    assert f"train_sflow.place_loss={rb.PLACE_WEIGHT}" in _sets(place)
    gait = stages["gait"][0]
    assert gait[gait.index("--from") + 1] == str(tmp_path / "runs" / "place" / "model")
    assert _sets(gait) == [*_sets(place), "train_sflow.repeat_scene_gait=true"]
    leader = stages["leader"][0]
    assert leader[leader.index("--from") + 1] == str(tmp_path / "runs" / "gait" / "model")
    assert leader[leader.index("--stages") + 1] == "pflow"
    assert "train_pflow.repeat_leader_gait=true" in _sets(leader)
    jump = stages["jump"][0]
    assert jump[jump.index("--from") + 1] == str(tmp_path / "runs" / "leader" / "model")
    assert jump[jump.index("--stages") + 1] == "pflow"
    assert _sets(jump) == [*_sets(leader), "train_pflow.label_repeats=[jump=4]"]
    final = tmp_path / "runs" / "jump" / "model"
    assert stages["name"][0][2:4] == [str(final), str(tmp_path / "model")]
    shipped = json.loads((ROOT / "src" / "umf" / "assets" / "model" / "format.json").read_text())
    assert stages["name"][0][-1] == rb.NAME == shipped["name"]
    config = json.loads((ROOT / "src" / "umf" / "assets" / "model" / "config.json").read_text())
    for option in rb.NAMED:  # every sampling option the name stage sets, the shipped model has
        key, value = option.split("=", 1)
        stage, field = key.split(".")
        assert json.dumps(config[stage][field]) == value or str(config[stage][field]) == value


def _sets(command: list[str]) -> list[str]:
    return [command[i + 1] for i, a in enumerate(command) if a == "--set"]


def test_stages_the_final_config_overwrites_keep_their_documented_options(tmp_path):
    """Options a later stage overwrites never reach the shipped config: pinned here as the
    results pages give them (h200-20261126, h200-20261126b, flows-long-h200-20261126,
    20261127b)."""
    stages = {st.name: st.commands for st in _script().stages(tmp_path, Path("out/corpus"))}
    gpu = _sets(stages["gpu"][0])
    for opt in ("train_vae.max_steps=2000", "train_vae.batch_size=128",
                "train_vae.warmup_steps=300", "train_pflow.max_steps=5600",
                "train_sflow.max_steps=5600", "train_pflow.batch_size=512",
                "train_sflow.batch_size=512", "train_pflow.lr=0.0004", "train_sflow.lr=0.0004",
                "train_pflow.ema_decay=0.999", "train_sflow.ema_decay=0.999",
                "train_pflow.latent_passes=6", "train_sflow.latent_passes=8"):  # fmt: skip
        assert opt in gpu, opt
    assert _sets(stages["rn0.5"][0]) == [
        "sflow.reaction_noise=0.5", "train_sflow.lr=0.0001", "train_sflow.warmup_steps=20",
        "train_sflow.batch_size=128", "train_sflow.latent_passes=2", "train_sflow.ema_decay=0.99",
        "train_sflow.ckpt_every=200", "train_sflow.num_workers=0", "train_sflow.max_steps=800",
        "train_sflow.val_every=200",
    ]  # fmt: skip
    sigmas = [_sets(stages[n][0])[0] for n in ("rn0.5b", "rn0.25c", "rn0.125d")]
    assert sigmas == ["sflow.reaction_noise=0.5", "sflow.reaction_noise=0.25",
                      "sflow.reaction_noise=0.125"]  # fmt: skip
    assert "train_sflow.max_steps=1600" in _sets(stages["rn0.5b"][0])
    assert _sets(stages["hg"][0]) == [
        "train_pflow.hold_rest=true", "train_pflow.repeat_gait=true",
        "train_pflow.respell_captions=true", "train_pflow.lr=0.0001",
        "train_pflow.warmup_steps=20", "train_pflow.max_steps=1000", "train_pflow.batch_size=128",
        "train_pflow.ema_decay=0.99", "train_pflow.latent_passes=4", "train_pflow.ckpt_every=250",
        "train_pflow.val_every=500", "train_pflow.num_workers=0",
    ]  # fmt: skip
    # --max-steps cuts every training stage last, so the cut wins
    cut = {st.name: st.commands for st in _script().stages(tmp_path, Path("out/corpus"), 3)}
    trained = {"gpu": ("vae", "pflow", "sflow"), "hg": ("pflow",), "dec": ("vae",),
               "mix": ("pflow",), "person": ("pflow", "sflow"), "person2": ("pflow", "sflow"),
               "place": ("sflow",), "gait": ("sflow",), "leader": ("pflow",), "jump": ("pflow",),
               **{n: ("sflow",) for n in ("rn0.5", "rn0.5b", "rn0.25c", "rn0.125d")}}  # fmt: skip
    for name, what in trained.items():
        last = {o.split("=")[0]: o.split("=")[1] for o in _sets(cut[name][0])}  # last one wins
        for stage in what:
            assert last[f"train_{stage}.max_steps"] == "3", name
            if stage != "vae":
                assert last[f"train_{stage}.latent_passes"] == "1", name


def test_dry_run_prints_every_stage_and_runs_nothing(tmp_path):
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dry-run", "--work", str(tmp_path / "w")],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )  # fmt: skip
    names = [line[3:] for line in out.stdout.splitlines() if line.startswith("== ")]
    assert names == ["gpu", "sampling", "rn0.5", "rn0.5b", "rn0.25c", "rn0.125d", "hg", "dec",
                     "mix", "teach", "reteach", "rebalance", "settle", "pace", "steps", "person",
                     "person2", "place", "gait", "leader", "jump", "name"]  # fmt: skip
    assert not (tmp_path / "w").exists()
    missing = subprocess.run(
        [sys.executable, str(SCRIPT), "--corpus", str(tmp_path / "nowhere"), "--work",
         str(tmp_path / "w2")],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert missing.returncode != 0 and "no corpus at" in missing.stderr
    assert "Traceback" not in missing.stderr


def test_every_script_a_stage_runs_exists(tmp_path):
    """The stages run other scripts by path (model_variant and the GPU driver): each one is
    there, among the maintainer's tools of scripts/."""
    commands = [c for st in _script().stages(tmp_path, Path("out/corpus")) for c in st.commands]
    paths = [Path(a) for c in commands for a in c if a.endswith((".py", ".sh"))]
    assert {p.parent.name for p in paths} == {"scripts"}
    assert all(p.is_file() for p in paths), [p for p in paths if not p.is_file()]


def test_prepare_like_rebuilds_a_manifest_with_more_train_scenes(tmp_path):
    """scripts/prepare_like.py: the manifest's sources and options, the train scenes changed;
    a source it cannot find or prepare is one error line."""
    import pytest

    from conftest import load_script

    pl = load_script("prepare_like")
    (tmp_path / "bandai").mkdir()
    (tmp_path / "salsa").mkdir()
    manifest = {"config": {"seed": 7, "train_scenes": 3000, "val_scenes": 20, "test_scenes": 30,
                           "test_groups": 10},
                "sources": [{"name": "bandai", "path": str(tmp_path / "bandai")},
                            {"name": "mocap-salsa", "path": str(tmp_path / "salsa")}]}  # fmt: skip
    cmd = pl.prepare_command(manifest, tmp_path / "out", 6000)
    assert cmd[1:5] == ["-m", "umf", "data", "prepare"]
    pairs = dict(zip(cmd[5::2], cmd[6::2], strict=False))
    assert pairs["--train-scenes"] == "6000" and pairs["--seed"] == "7"
    assert pairs["--val-scenes"] == "20" and pairs["--test-groups"] == "10"
    assert pairs["--bandai"] == str(tmp_path / "bandai")
    assert pairs["--mocap"] == str(tmp_path / "salsa")
    assert pl.prepare_command(manifest, tmp_path / "out", None)[
        cmd.index("--train-scenes") + 1] == "3000"  # fmt: skip
    manifest["sources"].append({"name": "mocap-gone", "path": str(tmp_path / "gone")})
    with pytest.raises(SystemExit, match="is gone"):
        pl.prepare_command(manifest, tmp_path / "out", 6000)
    manifest["sources"][-1] = {"name": "other", "path": str(tmp_path / "salsa")}
    with pytest.raises(SystemExit, match="no prepare option"):
        pl.prepare_command(manifest, tmp_path / "out", 6000)
