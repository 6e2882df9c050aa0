"""scripts/reproduce_bundled.py trains the bundled model again: its stages, applied in the
order their --init chain inherits configs, must give the shipped config.json."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

from umf.config import family_config, set_option

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "reproduce_bundled.py"


def _script():
    spec = importlib.util.spec_from_file_location("reproduce_bundled", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_stages_rebuild_the_shipped_config(tmp_path):
    rb = _script()
    stages = {name: commands for name, commands, _ in rb.stages(tmp_path, Path("out/corpus"))}
    # each stage's model is the next one's --init (or source), so configs carry over; the
    # P-Flow fine-tune "hg" is not in the chain of configs: the decoder stage starts from the
    # S-Flow's model and takes hg's P-Flow as its export --base (as the release did)
    chain = ["gpu", "sampling", "rn0.5", "rn0.5b", "rn0.25c", "rn0.125d", "dec", "mix"]
    cfg = family_config("small")
    for name in chain:
        command = stages[name][0]
        for i, arg in enumerate(command):
            if arg == "--set":
                cfg = set_option(cfg, command[i + 1])
    got = json.loads(json.dumps(cfg.to_dict()))  # tuples as lists, as in the file
    want = json.loads((ROOT / "src" / "umf" / "assets" / "model" / "config.json").read_text())
    # training fills text.respell from the corpus; logging cadence changes no weight
    for c in (got, want):
        c["text"].pop("respell")
        c["train_vae"].pop("log_every")
    assert got == want
    # and the chain is wired: every fine-tune starts from the model the stage before wrote
    inits = {n: c[0][c[0].index("--init") + 1] for n, c in stages.items() if "--init" in c[0]}
    assert inits["rn0.5"] == str(tmp_path / "models" / "sampling")
    assert inits["hg"] == inits["dec"] == str(tmp_path / "models" / "rn0.125d")
    assert inits["mix"] == str(tmp_path / "models" / "dec")
    assert stages["dec"][1][-1] == str(tmp_path / "models" / "hg")  # the P-Flow of hg
    shipped = json.loads((ROOT / "src" / "umf" / "assets" / "model" / "format.json").read_text())
    assert stages["name"][0][-1] == rb.NAME == shipped["name"]


def test_dry_run_prints_every_stage_and_runs_nothing(tmp_path):
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dry-run", "--work", str(tmp_path / "w")],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )  # fmt: skip
    names = [line[3:] for line in out.stdout.splitlines() if line.startswith("== ")]
    assert names == ["gpu", "sampling", "rn0.5", "rn0.5b", "rn0.25c", "rn0.125d", "hg", "dec",
                     "mix", "name"]  # fmt: skip
    assert not (tmp_path / "w").exists()
    missing = subprocess.run(
        [sys.executable, str(SCRIPT), "--corpus", str(tmp_path / "nowhere")],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert missing.returncode != 0 and "no corpus at" in missing.stderr
    assert "Traceback" not in missing.stderr
