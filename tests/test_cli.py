"""The `umf` command as a user runs it: real process, exit codes, one-line errors."""

import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest

from conftest import BANDAI_FIXTURE


def umf(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "umf.cli.main", *args], capture_output=True, text=True, cwd=cwd
    )


def test_help_everywhere():
    for args in ([], ["data"], ["data", "prepare"], ["data", "show"], ["data", "info"],
                 ["train"], ["train", "vae"], ["train", "all"], ["train", "export"],
                 ["train", "evaluator"], ["generate"], ["react"], ["eval"], ["serve"],
                 ["view"]):  # fmt: skip
        r = umf(*args, "--help")
        assert r.returncode == 0, r.stderr
        assert "Usage" in r.stdout
    assert umf("--version").stdout.startswith("umf ")


@pytest.fixture(scope="module")
def corpus_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "corpus"
    r = umf("data", "prepare", "--bandai", str(BANDAI_FIXTURE), "--out", str(out),
            "--train-scenes", "8", "--val-scenes", "2", "--test-scenes", "2", "--test-groups", "2",
            "--no-progress")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "corpus written" in r.stdout and "train" in r.stdout
    return out


def test_prepare_info_list_show(corpus_dir, tmp_path):
    r = umf("data", "info", str(corpus_dir))
    assert r.returncode == 0 and "relations:" in r.stdout
    r = umf("data", "list-items", str(corpus_dir), "--split", "test_groups")
    assert r.returncode == 0
    scene_id = r.stdout.splitlines()[0].split("\t")[0]
    gif = tmp_path / "scene.gif"
    r = umf(
        "data", "show", scene_id, "--corpus", str(corpus_dir), "--out", str(gif), "--stride", "4"
    )
    assert r.returncode == 0, r.stderr
    frames = iio.imread(gif, index=None)
    assert frames.ndim == 4 and frames.shape[0] > 5 and frames.std() > 5
    png = tmp_path / "clip.png"
    r = umf(
        "data", "show", "dataset-1_bow_normal_001", "--corpus", str(corpus_dir), "--out", str(png)
    )
    assert r.returncode == 0, r.stderr
    assert iio.imread(png).shape[1] > 1000


def test_show_reads_bvh_and_npz(tmp_path):
    bvh = (
        BANDAI_FIXTURE
        / "Bandai-Namco-Research-Motiondataset-1"
        / "data"
        / "dataset-1_bye_normal_001.bvh"
    )
    out = tmp_path / "bvh.gif"
    r = umf("data", "show", str(bvh), "--out", str(out), "--stride", "10")
    assert r.returncode == 0, r.stderr
    npz = tmp_path / "scene.npz"
    rng = np.random.default_rng(0)
    np.savez(npz, joints=rng.normal(size=(2, 5, 22, 3)).astype(np.float32), text="noise")
    r = umf("data", "show", str(npz), "--out", str(tmp_path / "n.gif"))
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize(
    "args, needle",
    [
        (["data", "prepare", "--out", "X"], "no data source"),
        (["data", "prepare", "--bandai", "/nonexistent", "--out", "X"], "not found"),
        (["data", "info", "/nonexistent"], "not a umf corpus"),
        (["data", "show", "missing.npz", "--out", "a.gif"], "file not found"),
        (["data", "show", "some-id", "--out", "a.gif"], "--corpus"),
        (["train", "vae", "--corpus", "/nonexistent", "--out", "run"], "not a umf corpus"),
        (["train", "vae", "--corpus", "c", "--out", "run", "--family", "huge"], "unknown config"),
        (["train", "vae", "--corpus", "c", "--out", "run", "--set", "vae.nope=1"], "nope"),
        (["train", "export", "--run", "nowhere", "--out", "m"], "config"),
        (
            ["train", "sflow", "--corpus", "c", "--out", "run", "--init", "nowhere"],
            "not a model directory",
        ),
        (["train", "vae", "--corpus", "c", "--out", "run", "--init", "src"], "not a model"),
    ],
)
def test_errors_are_one_line(args, needle, tmp_path):
    r = umf(*args, cwd=tmp_path)
    assert r.returncode != 0
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, r.stderr
    assert needle in lines[0] and "Traceback" not in r.stderr
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_bad_output_extension_leaves_nothing(tmp_path):
    bvh = (
        BANDAI_FIXTURE
        / "Bandai-Namco-Research-Motiondataset-1"
        / "data"
        / "dataset-1_bye_normal_001.bvh"
    )
    r = umf("data", "show", str(bvh), "--out", str(tmp_path / "a.avi"))
    assert r.returncode != 0 and len(r.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())
