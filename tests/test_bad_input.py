"""Bad input to every command: one line on stderr, a non-zero exit, nothing written.

Each case runs the real entry point (``umf.cli.main.run``) in-process against a tiny
untrained model, in a fresh directory whose whole tree is compared before and after.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE, save_tiny_model
from umf.cli.main import run

pytestmark = pytest.mark.usefixtures("one_thread", "fake_text")

BOW = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"


def _edit_config(model: Path, section: str, key: str, value) -> None:
    cfg = json.loads((model / "config.json").read_text())
    cfg[section][key] = value
    (model / "config.json").write_text(json.dumps(cfg))


def _bad_models(root: Path, good: Path) -> None:
    def copy(name: str) -> Path:
        return Path(shutil.copytree(good, root / name))

    pickled = root / "pickled"
    pickled.mkdir()
    torch.save({"state_dict": {}}, pickled / "model.pt")
    _edit_config(copy("types"), "vae", "d_model", "abc")
    _edit_config(copy("negative"), "vae", "num_layers", -3)
    _edit_config(copy("huge"), "vae", "d_model", 60000)
    _edit_config(copy("shape"), "vae", "d_model", 64)
    (copy("notjson") / "config.json").write_text("{")
    from safetensors.torch import load_file, save_file

    nan = copy("nan")
    weights = load_file(str(nan / "vae.safetensors"))
    first = next(iter(weights))
    weights[first] = torch.full_like(weights[first], float("nan"))
    save_file(weights, str(nan / "vae.safetensors"))
    (copy("nopflow") / "pflow.safetensors").unlink()
    zero = copy("zerostd")
    save_file({"mean": torch.zeros(262), "std": torch.zeros(262)},
              str(zero / "normalizer.safetensors"))  # fmt: skip


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    good = save_tiny_model(root / "good")
    _bad_models(root, good)
    return root


def _inputs(d: Path) -> None:
    """The files some cases name: actors, prompt files, a file where a directory goes."""
    pose = np.zeros((40, 22, 3), np.float32) + np.linspace(0, 1.7, 22, dtype=np.float32)[:, None]
    np.savez(d / "GOOD.npz", joints=pose)
    np.savez(d / "ZERO.npz", joints=np.zeros((40, 22, 3), np.float32))
    text = BOW.read_text()
    (d / "FT0.bvh").write_text(re.sub(r"Frame Time:\s*\S+", "Frame Time: 0", text, count=1))
    head, motion = text.split("Frame Time:", 1)
    rows = motion.split("\n")
    rows[1] = " ".join(["1e300", *rows[1].split()[1:]])  # a root position no float32 holds
    (d / "E300.bvh").write_text(head + "Frame Time:" + "\n".join(rows))
    (d / "two.txt").write_text("a person walks\ntwo people bow\n")
    (d / "afile").write_text("not a directory\n")
    (d / "adir").mkdir()
    (d / "out" / "00-x.npz").mkdir(parents=True)  # a directory where a file would go
    np.savez(d / "HUGE.npz", joints=pose * 1e4)  # 10,000 times a body's size: in no unit
    (d / "dangling").symlink_to(d / "nothing-here")
    libs = {  # mocap folders whose CSV files are broken
        "badcap": {"captions.csv": 'file,caption\na.bvh,"a person bows\nb.bvh,bows\n'},
        "extracap": {"captions.csv": "file,caption\na.bvh,bows,twice\n"},
        "hugedx": {"takes.csv": "take,file,person,dx,dz\nt,a.bvh,1,0,0\nt,b.bvh,2,1e30,0\n"},
    }
    for name, files in libs.items():
        (d / name).mkdir()
        for bvh in ("a.bvh", "b.bvh"):
            (d / name / bvh).write_text(text)
        for f, body in files.items():
            (d / name / f).write_text(body)


G = ["generate", "x", "--out", "out/new"]
R = ["react", "x", "--actor", "GOOD.npz", "--out", "out/new"]
T = ["train", "vae", "--corpus", "nowhere", "--out", "run"]
CASES = [
    # --people / --seconds / --seed / --guidance: range, type, NaN and infinities
    ([*G, "--people", "0"], 1, "--people must be between 1 and 16, got 0"),
    ([*G, "--people", "17"], 1, "--people must be between 1 and 16, got 17"),
    ([*G, "--people", "2.5"], 2, "Invalid value for '--people'"),
    ([*G, "--seconds", "nan"], 1, "--seconds must be a finite number"),
    ([*G, "--seconds", "inf"], 1, "--seconds must be a finite number"),
    ([*G, "--seconds", "0.1"], 1, "--seconds must be between 0.5 and 10"),
    ([*G, "--seconds", "60"], 1, "--seconds must be between 0.5 and 10"),
    ([*G, "--seconds", "9"], 1, "--seconds must be between 0.5 and 4.0"),  # the model's limit
    ([*G, "--device", "tpu"], 1, "--device must be auto, cpu or cuda[:i], got 'tpu'"),
    ([*G, "--seed", "-1"], 1, "--seed must be between 0 and"),
    ([*G, "--seed", str(2**64)], 1, "--seed must be between 0 and"),
    ([*G, "--guidance", "nan"], 1, "--guidance must be a finite number"),
    ([*G, "--guidance", "inf"], 1, "--guidance must be a finite number"),
    ([*G, "--guidance", "-1"], 1, "--guidance must be between 0 and 20"),
    # steps
    ([*G, "--steps", "1000000,1"], 1, "--steps must be between 1 and 200"),
    ([*G, "--steps", "150,100"], 1, "--steps may total at most 200"),
    ([*G, "--steps", "45,5,5"], 1, "--steps needs 2 count(s)"),
    ([*G, "--steps", "0,5"], 1, "--steps must be between 1 and 200, got 0"),
    ([*G, "--steps", "a,b"], 1, "--steps takes integers"),
    ([*G, "--steps", ""], 1, "--steps takes integers"),
    ([*G, "--sflow-steps", "0"], 1, "--sflow-steps must be between 1 and 200, got 0"),
    ([*G, "--sflow-steps", "-1"], 1, "--sflow-steps must be between 1 and 200"),
    ([*G, "--sflow-steps", "100000"], 1, "--sflow-steps must be between 1 and 200"),
    # batch, prompts, formats
    ([*G, "--batch", "0"], 1, "--batch must be between 1 and 256"),
    ([*G, "--batch", "257"], 1, "--batch must be between 1 and 256"),
    (
        ["generate", "--prompts", "two.txt", "--batch", "200", "--out", "out/new"],
        1,
        "at most 256 scenes per command",
    ),
    (["generate", " ", "--out", "out/new"], 1, "the prompt is empty"),
    (["generate", "--out", "out/new"], 1, "give a prompt or --prompts FILE"),
    (["generate", "w" * 2000, "--out", "out/new"], 1, "at most 1000 characters"),
    (["generate", "--prompts", "missing.txt", "--out", "out/new"], 1, "cannot read prompts"),
    (["generate", "--prompts", "adir", "--out", "out/new"], 1, "cannot read prompts"),
    ([*G, "--format", "xyz"], 1, "unknown format 'xyz'"),
    ([*G, "--format", ","], 1, "unknown format"),
    # output directory
    (["generate", "x", "--out", "afile"], 1, "--out afile exists and is not a directory"),
    (["generate", "x", "--out", "afile/sub"], 1, "afile is not a directory"),
    (["generate", "x", "--out", "out"], 1, "a directory has that name"),
    (["generate", "x", "--out", "dangling"], 1, "--out dangling is a symbolic link to nothing"),
    ([*G, "--bogus"], 2, "No such option: --bogus"),
    # ports
    ([*G, "--view", "--port", "-1"], 1, "--port must be 0-65535 (0: any free port), got -1"),
    (["view", "GOOD.npz", "--port", "70000", "--no-open"], 1, "--port must be 0-65535"),
    (["serve", "--port", "65536"], 1, "--port must be 0-65535"),
    # model directories
    ([*G, "--model", "nowhere"], 1, "model not found"),
    ([*G, "--model", "afile"], 1, "model not found"),
    ([*G, "--model", "{models}/pickled"], 1, "not a umf checkpoint (no format.json)"),
    ([*G, "--model", "{models}/types"], 1, "vae.d_model must be an integer, got 'abc'"),
    ([*G, "--model", "{models}/negative"], 1, "vae.num_layers must be between 0 and 256"),
    ([*G, "--model", "{models}/huge"], 1, "GiB of weights"),
    ([*G, "--model", "{models}/shape"], 1, "in the checkpoint but"),
    ([*G, "--model", "{models}/notjson"], 1, "config.json: unreadable"),
    ([*G, "--model", "{models}/nan"], 1, "contain NaN or infinite values"),
    ([*G, "--model", "{models}/zerostd"], 1, "normaliser has a zero or negative std"),
    # react
    ([*R, "--start", "nan"], 1, "--start must be a finite number"),
    ([*R, "--start", "-1"], 1, "--start must be between 0"),
    ([*R, "--start", "60"], 1, "--start 60.0 s is outside the actor motion"),
    ([*R, "--seconds", "-1"], 1, "--seconds must be between 0.5 and 10"),
    ([*R, "--seconds", "5"], 1, "the actor motion has only 1.3 s after --start"),
    ([*R, "--people", "1"], 1, "at least 2"),
    ([*R, "--guidance", "nan"], 1, "--guidance must be a finite number"),
    ([*R, "--batch", "0"], 1, "--batch must be between 1 and 256"),
    (["react", "x", "--actor", "ZERO.npz", "--out", "out/new"], 1, "not a body"),
    (["react", "x", "--actor", "HUGE.npz", "--out", "out/new"], 1, "a person's size in no unit"),
    (["view", "HUGE.npz", "--no-open"], 1, "a body 3.08e+04 units tall"),
    (["data", "show", "HUGE.npz", "--out", "x.gif"], 1, "a person's size in no unit"),
    (
        ["data", "show", "GOOD.npz", "--out", "x.gif", "--stride", "100000"],
        1,
        "--stride must be between 1 and 39, got 100000",
    ),
    (["react", "x", "--actor", "FT0.bvh", "--out", "out/new"], 1, "Frame Time: 0"),
    (["react", "x", "--actor", "E300.bvh", "--out", "out/new"], 1, "NaN or infinite values"),
    (["react", "x", "--actor", "missing.bvh", "--out", "out/new"], 1, "file not found"),
    # eval, data, train
    (["eval", "--checkpoint", "m", "--device", "tpu"], 1, "--device must be auto, cpu or cuda"),
    (["eval", "--checkpoint", "m", "--out", "afile"], 1, "--out afile exists and is not a dir"),
    (
        ["data", "prepare", "--bandai", str(BANDAI_FIXTURE), "--out", "afile"],
        1,
        "--out afile exists and is not a directory",
    ),
    # a broken CSV of a mocap folder: one line naming it, and no corpus folder left behind
    (
        ["data", "prepare", "--mocap", "badcap", "--out", "c", "--no-progress"],
        1,
        "badcap/captions.csv, line 2: a field runs over several lines (a quote left open?)",
    ),
    (
        ["data", "prepare", "--mocap", "extracap", "--out", "c", "--no-progress"],
        1,
        "extracap/captions.csv, line 2: 3 fields, the header names 2",
    ),
    (
        ["data", "prepare", "--mocap", "hugedx", "--out", "c", "--no-progress"],
        1,
        "takes.csv, line 3: person must be 1..16 and dx/dz metres within ±100",
    ),
    # fine-tuning: everything it needs, checked before anything is written
    (
        ["train", "finetune", "--from", "{models}/good", "--corpus", "nowhere", "--out", "afile"],
        1,
        "--out afile exists and is not a directory",
    ),
    (
        ["train", "finetune", "--from", "{models}/nopflow", "--corpus", "nowhere", "--out", "run"],
        1,
        "missing module file pflow.safetensors",
    ),
    (
        [
            "train",
            "finetune",
            "--from",
            "{models}/good",
            "--corpus",
            "nowhere",
            "--out",
            "run",
            "--accelerator",
            "tpu",
        ],
        1,
        "cannot set up training on tpu",
    ),
    # info: a damaged model is an error, not a description
    (["info", "{models}/notjson"], 1, "config.json: unreadable"),
    (["info", "{models}/nopflow"], 1, "missing module file pflow.safetensors"),
    (["info", "{models}/good", "--prompt", " "], 1, "the prompt is empty"),
    (
        ["info", "{models}/good", "--prompt", "walk"],
        1,
        "cannot score --prompt: this model carries no vocabulary",
    ),
    (
        ["data", "prepare", "--bandai", str(BANDAI_FIXTURE), "--out", "c", "--train-scenes", "-1"],
        1,
        "--train-scenes must be between 1",
    ),
    (
        ["data", "prepare", "--bandai", str(BANDAI_FIXTURE), "--out", "c", "--val-scenes", "-5"],
        1,
        "--val-scenes must be between 0",
    ),
    ([*T, "--set", "vae.d_model=-1"], 1, "vae.d_model must be between 0 and 65536"),
    ([*T, "--set", "vae.num_heads=5"], 1, "cannot be built: embed_dim must be divisible"),
    ([*T, "--set", "pflow.steps=[0,5]"], 1, "pflow.steps must be between 1 and 200"),
    ([*T, "--set", "sflow.pair_steps=0"], 1, "sflow.pair_steps must be between 1 and 200"),
    ([*T, "--set", "sflow.pair_steps=201"], 1, "sflow.pair_steps must be between 1 and 200"),
    ([*T, "--set", "train_vae.lr=-1"], 1, "need lr > 0"),
    (
        [*T, "--set", "train_pflow.balance_labels=-1"],
        1,
        "train_pflow.balance_labels must be between 0 and 1",
    ),
    ([*T, "--set", "train_pflow.balance_labels=2"], 1, "balance_labels must be between 0 and 1"),
    ([*T, "--set", "train_pflow.caption_mix=1.5"], 1, "caption_mix must be between 0 and 1"),
    (
        [*T, "--set", "train_pflow.caption_mix_from=[normal]"],
        1,
        "train_pflow.caption_mix_from takes key=value pairs",
    ),
    ([*T, "--set", "train_pflow.labels=[1]"], 1, "train_pflow.labels must be a list of words"),
    ([*T, "--set", "train_pflow.labels=wave"], 1, "train_pflow.labels must be a list"),
    ([*T, "--set", "train_sflow.labels=[wave]"], 1, "train_sflow.labels: only the VAE and P-Flow"),
    (
        [*T, "--set", "train_sflow.label_repeats=[wave=2]"],
        1,
        "train_sflow.label_repeats: only the VAE and P-Flow",
    ),
    (
        [*T, "--set", "train_pflow.label_repeats=[wave]"],
        1,
        "label_repeats takes key=value pairs (e.g. jump=4)",
    ),
    ([*T, "--set", "sflow.reaction_noise=-0.5"], 1, "sflow.reaction_noise must be between 0 and"),
    (
        [*T, "--set", "train_pflow.respell_captions=maybe"],
        1,
        "train_pflow.respell_captions must be true or false",
    ),
]


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.lstat().st_size, p.lstat().st_mtime_ns)
            for p in root.rglob("*")}  # fmt: skip


# a warning would be lines of its own on a user's stderr (pytest keeps them off capsys)
@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize(("args", "code", "message"), CASES, ids=[" ".join(c[0])[:60]
                                                                    for c in CASES])  # fmt: skip
def test_bad_input(args, code, message, models, tmp_path, monkeypatch, capsys):
    _inputs(tmp_path)
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{models}", str(models)) for a in args]
    if "--model" not in args and args[0] in ("generate", "react"):
        args += ["--model", str(models / "good")]
    before = _tree(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        run(args)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert exit_.value.code == code, err
    assert len(lines) == 1 and lines[0].startswith("umf: error: "), err
    assert message in lines[0], lines[0]
    assert _tree(tmp_path) == before  # nothing written, nothing removed


@pytest.mark.parametrize("command", [["eval", "--checkpoint", "m"], ["generate", "x"]])
def test_no_cuda_is_one_line(tmp_path, monkeypatch, capsys, command):
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)
    with pytest.raises(SystemExit) as exit_:
        run([*command, "--device", "cuda", "--out", str(tmp_path / "r")])
    assert exit_.value.code == 1
    assert (
        capsys.readouterr().err.strip()
        == "umf: error: --device cuda: no CUDA device on this machine"
    )
    assert not (tmp_path / "r").exists()  # refused before anything is written


def test_python_dash_m_umf(tmp_path):
    """`python -m umf` is the same command, with the same one-line errors."""
    r = subprocess.run([sys.executable, "-m", "umf", "generate", "x", "--seconds", "nan",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 1
    assert r.stderr.strip() == "umf: error: --seconds must be a finite number, got nan"
    assert not list(tmp_path.iterdir())
    r = subprocess.run([sys.executable, "-m", "umf", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("umf ")


def test_sigterm_ends_a_run_as_ctrl_c_does(models, tmp_path, monkeypatch, capsys):
    """SIGTERM (kill, docker stop): exit 143, one line, no temporary folder or partial file,
    even where the signal's exception comes out of a C extension as another (a TypeError
    from matplotlib, seen while a GIF was drawn)."""
    import os
    import signal
    import time

    import umf.writer

    def killed(scene, stem, wanted):
        stem.with_suffix(".npz").write_bytes(b"half a file")
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises at the next bytecode
        except KeyboardInterrupt:
            raise TypeError("incompatible function arguments") from None

    monkeypatch.setattr(umf.writer, "write_formats", killed)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(SystemExit) as exit_:
        run(["generate", "x", "--seconds", "1", "--model", str(models / "good"),
             "--out", str(tmp_path / "o")])  # fmt: skip
    assert exit_.value.code == 143
    assert capsys.readouterr().err.strip() == "umf: terminated"
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]
    assert signal.getsignal(signal.SIGTERM) is before  # the caller's handler is back
