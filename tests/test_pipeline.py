"""End to end on the bundled real clips: train all stages briefly, export, load, generate."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE, TINY_MODEL, prepare_fixture_corpus, save_tiny_model
from umf.config import set_option, small_config
from umf.errors import UMFError
from umf.pipeline import UMFPipeline, delivered_joints
from umf.representation import CONTACT
from umf.train.run import Launch, export_model, train_stage

TINY = list(TINY_MODEL)
for s in ("vae", "pflow", "sflow"):
    TINY += [
        f"train_{s}.{k}"
        for k in (
            "batch_size=4",
            "max_steps=4",
            "val_every=2",
            "ckpt_every=2",
            "warmup_steps=1",
            "max_frames=60",
        )
    ]
TINY += ["train_pflow.latent_passes=2"]  # P-Flow from a latent bank, S-Flow per batch


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("e2e")
    prepare_fixture_corpus(root / "corpus", train_scenes=12, val_scenes=4, test_scenes=4,
                           test_groups=2)  # fmt: skip
    cfg = small_config()
    for o in TINY:
        cfg = set_option(cfg, o)
    launch = Launch(progress=False)
    summaries = {
        s: train_stage(s, root / "corpus", root / "run", cfg, launch, log=lambda m: None)
        for s in ("vae", "pflow", "sflow")
    }
    model = export_model(root / "run", root / "model")
    return root, model, summaries


def test_all_stages_train_and_export(trained):
    root, model, summaries = trained
    # training wrote the corpus's spellings into the model (text.respell, never None after)
    assert UMFPipeline.from_pretrained(model).config.text.respell is not None
    for s, summary in summaries.items():
        assert summary["steps"] == 4, s
        assert (root / "run" / s / "metrics.csv").exists()
        assert (root / "run" / s / "loss_curves.png").exists()
    assert {p.name for p in model.iterdir()} >= {
        "format.json", "config.json", "vae.safetensors", "pflow.safetensors",
        "sflow.safetensors", "normalizer.safetensors",
    }  # fmt: skip


@pytest.mark.parametrize("num_people", [1, 3])
def test_generate_any_number_of_people(trained, num_people, tmp_path):
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    scenes = pipe(["two people bow to each other", "a person waves"], num_people=num_people,
                  seconds=2.0, seed=3)  # fmt: skip
    assert len(scenes) == 2
    for s in scenes:
        assert s.joints.shape == (num_people, 60, 22, 3)
        assert s.features.shape == (num_people, 60, 262)
        assert np.isfinite(s.joints).all()
    again = pipe(["two people bow to each other", "a person waves"], num_people=num_people,
                 seconds=2.0, seed=3)  # fmt: skip
    assert np.array_equal(again[0].joints, scenes[0].joints)  # seeded
    other = pipe("two people bow to each other", num_people=num_people, seconds=2.0, seed=4)
    assert not np.array_equal(other[0].joints, scenes[0].joints)
    rot = scenes[0].rotations()
    assert rot.shape == (num_people, 60, 22, 3, 3)
    assert np.allclose(np.linalg.det(rot), 1.0, atol=1e-4)
    path = scenes[0].save_npz(tmp_path / "scene.npz")
    with np.load(path) as z:
        assert z["joints"].shape == (num_people, 60, 22, 3) and str(z["text"]).startswith("two")


def test_nfe_follows_the_step_budget(trained):
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    s = pipe("a person walks", num_people=3, seconds=1.0, seed=0)[0]
    # P-Flow 4 + 2 steps, S-Flow 3 steps for each of the 2 further people (Euler: 1 NFE/step)
    assert s.meta["nfe"] == 6 + 2 * 3


def test_bad_requests(trained):
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    with pytest.raises(UMFError, match="empty"):
        pipe("  ", num_people=2)
    with pytest.raises(UMFError, match="people"):
        pipe("hi", num_people=0)
    with pytest.raises(UMFError, match="seconds"):
        pipe("hi", num_people=2, seconds=100.0)
    with pytest.raises(UMFError, match="model not found"):
        UMFPipeline.from_pretrained(model.parent / "nope")


def test_corrupt_model_is_one_clear_error(trained, tmp_path):
    import shutil

    _, model, _ = trained
    bad = tmp_path / "bad"
    shutil.copytree(model, bad)
    (bad / "pflow.safetensors").write_bytes(b"garbage")
    with pytest.raises(UMFError, match="pflow"):
        UMFPipeline.from_pretrained(bad)
    (bad / "pflow.safetensors").unlink()
    with pytest.raises(UMFError):
        UMFPipeline.from_pretrained(bad)


def test_react_keeps_the_actor(trained, bandai_clips):
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    actor = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0][:61]
    s = pipe("two people bow to each other", num_people=2, actor=actor, seed=0)[0]
    assert s.joints.shape == (2, 60, 22, 3)
    # the actor is fitted like everyone (one rigid body): a real, rigid skeleton comes back
    # to float precision
    assert np.allclose(s.joints[0], actor[:60], atol=1e-6)
    assert torch.isfinite(torch.from_numpy(s.joints)).all()


def test_generate_cli_writes_files_people_can_open(trained, tmp_path):
    """`umf generate` end to end: npz + BVH per person + GIF; BVH read back by bvhio."""
    import subprocess
    import sys

    import imageio.v3 as iio

    from test_bvh import bvhio_positions
    from umf.skeleton import JOINT_NAMES

    _, model, _ = trained
    out = tmp_path / "gen"
    r = subprocess.run(
        [sys.executable, "-m", "umf.cli.main", "generate", "two people bow to each other",
         "--people", "3", "--seconds", "1", "--format", "npz,bvh,gif", "--out", str(out),
         "--model", str(model), "--seed", "5"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    with np.load(out / "00-two-people-bow-to-each-other.npz") as z:
        joints = z["joints"]
        assert joints.shape == (3, 30, 22, 3) and int(z["seed"]) == 5
    for i in range(3):
        bvh = out / f"00-two-people-bow-to-each-other-p{i + 1}.bvh"
        assert f"wrote {bvh}" in r.stdout
        names, pos = bvhio_positions(bvh, list(range(0, 30, 7)))
        order = [names.index(n) for n in JOINT_NAMES]
        # a tiny untrained model's bones stretch, so only the pelvis path is exact here;
        # test_save_bvh_round_trip checks the whole skeleton on real motion
        err = np.linalg.norm(pos[:, order[0]] - joints[i, 0:30:7, 0], axis=-1)
        assert err.max() < 1e-4
    frames = iio.imread(out / "00-two-people-bow-to-each-other.gif", index=None)
    assert frames.shape[0] == 30
    bad = subprocess.run(
        [sys.executable, "-m", "umf.cli.main", "generate", "x", "--format", "fbx",
         "--model", str(model), "--out", str(tmp_path / "bad")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "bad").exists()


def test_save_bvh_round_trip(bandai_clips, tmp_path):
    """BVH per person, read back by bvhio, reproduces a real two-person scene within 1 cm."""
    from test_bvh import bvhio_positions
    from umf.pipeline import Scene
    from umf.skeleton import JOINT_NAMES

    a = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0][:90]
    b = next(c for c in bandai_clips if c.id == "dataset-1_bye_normal_001").joints[0][:90]
    b = b + np.array([0.0, 0.0, 2.0], np.float32)
    joints = np.stack([a, b])
    scene = Scene(joints, np.zeros((2, 90, 262), np.float32), "two people greet", 30.0)
    paths = scene.save_bvh(tmp_path / "greet-p{i}.bvh")
    assert [p.name for p in paths] == ["greet-p1.bvh", "greet-p2.bvh"]
    for i, path in enumerate(paths):
        names, pos = bvhio_positions(path, list(range(0, 90, 11)))
        order = [names.index(n) for n in JOINT_NAMES]
        err = np.linalg.norm(pos[:, order] - joints[i, 0:90:11], axis=-1)
        assert err.max() < 0.01, err.max()


def test_react_maps_back_into_the_actor_frame(trained, bandai_clips):
    """Moving and turning the actor moves and turns every generated person the same way:
    the model sees the actor canonically and the scene goes back to the user's frame."""
    from umf.representation import RigidTransform

    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    actor = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0][:61]
    base = pipe("two people bow to each other", num_people=3, actor=actor, seed=1)[0]
    move = RigidTransform(yaw=1.1, origin=(-4.0, 0.0, 2.5))  # x' = R (x - origin)
    moved_actor = move.apply(torch.from_numpy(actor)).numpy()
    moved = pipe("two people bow to each other", num_people=3, actor=moved_actor, seed=1)[0]
    expect = move.apply(torch.from_numpy(base.joints)).numpy()
    assert np.abs(moved.joints - expect).max() < 1e-3
    assert np.allclose(moved.joints[0], moved_actor[:60], atol=1e-6)
    # features follow the decoded joints: positions slot = raw joints, velocities = differences
    raw = moved.raw_joints
    assert np.allclose(moved.features[..., :66].reshape(3, 60, 22, 3), raw, atol=1e-6)
    vel = moved.features[:, :-1, 66:132].reshape(3, 59, 22, 3)
    assert np.abs(vel[0] - np.diff(raw[0], axis=0)).max() < 1e-5


def test_ten_people(trained):
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    s = pipe("ten people gather around a caller", num_people=10, seconds=1.0, seed=0)[0]
    assert s.joints.shape == (10, 30, 22, 3) and np.isfinite(s.joints).all()
    assert s.meta["nfe"] == 6 + 9 * 3
    from test_separation import _pelvis_gaps

    assert min(_pelvis_gaps(s.joints)) >= 0.5 - 1e-4  # nobody on top of anybody
    raw = pipe("ten people gather around a caller", num_people=10, seconds=1.0, seed=0,
               separate=False)[0]  # fmt: skip
    shifts = np.asarray(s.meta["shifts"])
    assert np.allclose(s.joints, raw.joints + shifts[:, None, None, :], atol=1e-5)
    with pytest.raises(UMFError, match="people"):
        pipe("hi", num_people=17)


def test_delivered_joints_redo_the_default_call(trained):
    """`umf eval` scores fit=False scenes also "as delivered": it must get what users get."""
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)
    full = pipe("four people dance in a circle", num_people=4, seconds=1.5, seed=2)[0]
    raw = pipe("four people dance in a circle", num_people=4, seconds=1.5, seed=2,
               separate=False, fit=False)[0]  # fmt: skip
    got = delivered_joints(raw.raw_joints, raw.features[..., CONTACT])
    assert got.shape == full.joints.shape == (4, 45, 22, 3)
    assert np.allclose(got, full.joints, atol=1e-4)
    assert np.abs(got - raw.raw_joints).max() > 1e-3  # the clean-up changed something
    kept = pipe("four people dance in a circle", num_people=4, seconds=1.5, seed=2,
                anchor=False)[0]  # fmt: skip
    assert np.allclose(delivered_joints(raw.raw_joints, raw.features[..., CONTACT], anchor=False),
                       kept.joints, atol=1e-4)  # fmt: skip
    assert not np.allclose(kept.joints, full.joints, atol=1e-3)
    one = pipe("a person waves", num_people=1, seconds=1.0, seed=0)[0]  # fitted, not separated
    bare = pipe("a person waves", num_people=1, seconds=1.0, seed=0, fit=False)[0]
    assert np.allclose(delivered_joints(bare.raw_joints, bare.features[..., CONTACT]),
                       one.joints, atol=1e-4)  # fmt: skip


def _umf(*args: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "umf.cli.main", *args],
                          capture_output=True, text=True)  # fmt: skip


def test_generate_cli_no_anchor_keeps_the_decoded_path(trained, tmp_path):
    """--no-anchor writes what pipe(..., anchor=False) makes; the default anchors feet."""
    from typer.testing import CliRunner

    from umf.cli.main import app

    _, model, _ = trained
    got = {}
    for flag in ("--anchor", "--no-anchor"):
        out = tmp_path / flag
        r = CliRunner().invoke(app, ["generate", "two people bow", "--people", "2", "--seconds",
                                     "1", "--format", "npz", "--out", str(out), "--model",
                                     str(model), "--seed", "4", flag])  # fmt: skip
        assert r.exit_code == 0, r.output
        with np.load(out / "00-two-people-bow.npz") as z:
            got[flag] = z["joints"]
    pipe = UMFPipeline.from_pretrained(model)
    for flag, anchor in (("--anchor", True), ("--no-anchor", False)):
        want = pipe("two people bow", num_people=2, seconds=1.0, seed=4, anchor=anchor)[0]
        assert np.allclose(got[flag], want.joints, atol=1e-5), flag
    assert not np.allclose(got["--anchor"], got["--no-anchor"], atol=1e-3)


def test_react_cli_with_a_bvh_actor(trained, tmp_path):
    """`umf react`: a real Bandai BVH (centimetres) as person 1, two people generated."""
    _, model, _ = trained
    bvh = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"
    out = tmp_path / "react"
    r = _umf("react", "two people bow to each other", "--actor", str(bvh), "--people", "3",
             "--seconds", "2", "--format", "npz,glb", "--out", str(out),
             "--model", str(model))  # fmt: skip
    assert r.returncode == 0, r.stderr
    npz = out / "react-two-people-bow-to-each-other.npz"
    assert f"wrote {npz}" in r.stdout and npz.with_suffix(".glb").exists()
    from umf.data.motion_file import load_motion

    actor = load_motion(bvh).joints[0]
    with np.load(npz) as z:
        assert z["joints"].shape == (3, 60, 22, 3)
        assert np.allclose(z["joints"][0], actor[:60], atol=1e-5)  # the user's own frame


def test_generate_batch_and_prompt_file(trained, tmp_path):
    _, model, _ = trained
    prompts = tmp_path / "prompts.txt"
    prompts.write_text("two people bow to each other\n\n# a comment\na person waves\n")
    out = tmp_path / "gen"
    r = _umf("generate", "--prompts", str(prompts), "--batch", "2", "--people", "2",
             "--seconds", "1", "--format", "npz", "--out", str(out),
             "--model", str(model))  # fmt: skip
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in out.iterdir())
    bow = "00-two-people-bow-to-each-other"
    assert names == [f"{bow}-0.npz", f"{bow}-1.npz",
                     "01-a-person-waves-0.npz", "01-a-person-waves-1.npz"]  # fmt: skip
    with np.load(out / names[0]) as a, np.load(out / names[1]) as b:
        assert not np.array_equal(a["joints"], b["joints"])  # two samples, not one twice


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["generate", "x", "--people", "0"], "people"),
        (["generate", "x", "--people", "17"], "people"),
        (["generate", " "], "empty"),
        (["generate", "x", "--seconds", "60"], "seconds"),
        (["generate", "x", "--batch", "0"], "batch"),
        (["generate", "x", "--steps", "a,b"], "steps"),
        (["react", "x", "--actor", "missing.bvh"], "not found"),
        (["react", "x", "--actor", "BAD.bvh"], "BAD.bvh"),
        (["react", "x", "--actor", "BAD.npz"], "BAD.npz"),
        (["react", "", "--actor", "BAD.npz"], "empty"),
        (["react", "x", "--actor", "GOOD.npz", "--people", "1"], "at least 2"),
        (["react", "x", "--actor", "GOOD.npz", "--actor-person", "2"], "no person 2"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(trained, tmp_path, args, needle):
    _, model, _ = trained
    (tmp_path / "BAD.bvh").write_text("HIERARCHY\nROOT x {\n")
    (tmp_path / "BAD.npz").write_bytes(b"not a zip")
    np.savez(tmp_path / "GOOD.npz", joints=np.zeros((40, 22, 3)) + np.linspace(0, 1.7, 22)[:, None])
    args = [str(tmp_path / a) if a.endswith((".bvh", ".npz")) else a for a in args]
    r = _umf(*args, "--model", str(model), "--out", str(tmp_path / "out"))
    assert r.returncode == 1, r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and needle in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_missing_or_corrupt_model_from_the_cli(trained, tmp_path):
    import shutil

    _, model, _ = trained
    r = _umf("generate", "x", "--model", str(tmp_path / "none"), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "model not found" in r.stderr
    bad = tmp_path / "bad"
    shutil.copytree(model, bad)
    (bad / "vae.safetensors").write_bytes(b"\x00" * 10)
    r = _umf("generate", "x", "--model", str(bad), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "o").exists()


def test_pair_steps_apply_to_two_people_only(trained, tmp_path):
    """A model's ``sflow.pair_steps`` sets the S-Flow steps of pairs; groups keep ``steps``
    and a caller's ``sflow_steps`` overrides both."""
    _, model, _ = trained
    copy = Path(shutil.copytree(model, tmp_path / "model"))
    cfg = json.loads((copy / "config.json").read_text())
    cfg["sflow"]["pair_steps"] = 1
    (copy / "config.json").write_text(json.dumps(cfg))
    pipe = UMFPipeline.from_pretrained(copy)
    nfe = {n: pipe("a person walks", num_people=n, seconds=1.0, seed=0)[0].meta["nfe"]
           for n in (2, 3)}  # fmt: skip
    assert nfe == {2: 6 + 1, 3: 6 + 2 * 3}  # P-Flow 4 + 2; S-Flow 1 for pairs, 3 per person
    s = pipe("a person walks", num_people=2, seconds=1.0, seed=0, sflow_steps=2)[0]
    assert s.meta["nfe"] == 6 + 2


def test_a_flow_stage_fine_tunes_from_a_model(trained, tmp_path):
    """--init: a fresh run takes the model's VAE, and its S-Flow starts from the model's
    weights (and latent statistics), not from a new initialisation."""
    from umf.checkpoint import read_weights

    root, _, _ = trained
    model = save_tiny_model(tmp_path / "source", seed=7)  # not the run's own initialisation
    cfg = small_config()
    tuning = ["train_sflow.lr=0.000000001", "train_sflow.warmup_steps=0", "train_sflow.max_steps=2"]
    for o in [*TINY, *tuning]:
        cfg = set_option(cfg, o)
    run = tmp_path / "ft"
    logs: list[str] = []
    train_stage("sflow", root / "corpus", run, cfg, Launch(progress=False), init=model,
                log=logs.append)  # fmt: skip
    assert (run / "vae" / "best" / "vae.safetensors").exists()
    assert any("starting from the weights" in m for m in logs)
    start = read_weights(model, "sflow")
    tuned = read_weights(run / "sflow" / "last", "sflow")
    assert start.keys() == tuned.keys()
    for k in start:  # lr ~0: the weights it trained are the ones it started from
        assert torch.allclose(tuned[k].float(), start[k].float(), atol=1e-3), k
    with pytest.raises(UMFError, match="--base MODEL_DIR"):
        export_model(run, tmp_path / "tuned")  # no P-Flow trained in this run
    tuned_model = export_model(run, tmp_path / "tuned", base=model, log=logs.append)
    pipe = UMFPipeline.from_pretrained(tuned_model)
    assert pipe(["two people bow"], num_people=2, seconds=1.0, seed=0)[0].joints.shape[0] == 2
    assert "pflow: from" in " ".join(logs)
    kept, source = read_weights(tuned_model, "pflow"), read_weights(model, "pflow")
    assert kept.keys() == source.keys()
    assert all(torch.allclose(kept[k].float(), source[k].float(), atol=1e-3) for k in kept)
    resumed: list[str] = []  # a resumed run keeps its own checkpoint, not the model's
    train_stage("sflow", root / "corpus", run, cfg, Launch(progress=False), init=model,
                resume=True, log=resumed.append)  # fmt: skip
    assert any("is not used" in m for m in resumed)
    other = save_tiny_model(tmp_path / "other", seed=8)
    with pytest.raises(UMFError, match="not the one of"):  # its S-Flow knows another VAE
        train_stage("pflow", root / "corpus", run, cfg, Launch(progress=False), init=other)
    with pytest.raises(UMFError, match="not a model directory"):
        train_stage("sflow", root / "corpus", tmp_path / "bad", cfg, Launch(progress=False),
                    init=tmp_path)  # fmt: skip


def test_pflow_detail_norm_fine_tunes_from_a_model_without_it(trained, tmp_path, monkeypatch):
    """pflow.detail_norm on a model trained without it: the weights and the latent mean and
    std are the model's, the detail gains are fitted under them, and the exported model
    carries and uses them."""
    from safetensors.torch import load_file, save_file

    from umf.checkpoint import read_weights
    from umf.flows.pyramid import down, up
    from umf.models.latent_normalizer import MAX_DETAIL_GAIN, LatentNormalizer

    root, _, _ = trained
    model = save_tiny_model(tmp_path / "source", seed=7)
    weights = load_file(model / "pflow.safetensors")  # a distinctive latent mean and std
    weights["latent_norm.mean"] = weights["latent_norm.mean"] + 1.0
    weights["latent_norm.std"] = weights["latent_norm.std"] * 3.0
    save_file(weights, str(model / "pflow.safetensors"))
    seen: list[tuple[torch.Tensor, ...]] = []
    fit_detail = LatentNormalizer.fit_detail

    def recording(self, z):
        seen.append((self.mean.clone(), self.std.clone(), z.clone()))
        return fit_detail(self, z)

    monkeypatch.setattr(LatentNormalizer, "fit_detail", recording)
    cfg = small_config()
    tuning = ["train_pflow.lr=0.000000001", "train_pflow.warmup_steps=0",
              "train_pflow.max_steps=2", "pflow.detail_norm=true"]  # fmt: skip
    for o in [*TINY, *tuning]:
        cfg = set_option(cfg, o)
    run = tmp_path / "ft"
    train_stage("pflow", root / "corpus", run, cfg, Launch(progress=False), init=model,
                log=lambda m: None)  # fmt: skip
    start, tuned = read_weights(model, "pflow"), read_weights(run / "pflow" / "last", "pflow")
    assert set(tuned) - set(start) == {"latent_norm.detail_gain"}
    for k in start:  # lr ~0; the latent mean and std are the model's
        assert torch.allclose(tuned[k].float(), start[k].float(), atol=1e-3), k
    mean, std, z = seen[-1]  # the last fit: under the model's mean and std
    torch.testing.assert_close(mean.float(), start["latent_norm.mean"].float())
    torch.testing.assert_close(std.float(), start["latent_norm.std"].float())
    x = (z.double() - mean.double()) / std.double()
    rms = (x - up(down(x, "1d"), "1d")).pow(2).mean(dim=(0, 1)).sqrt()
    gain = tuned["latent_norm.detail_gain"].float()
    torch.testing.assert_close(gain, (1 / rms).clamp_max(MAX_DETAIL_GAIN).float())
    tuned_model = export_model(run, tmp_path / "tuned", base=model, log=lambda m: None)
    pipe = UMFPipeline.from_pretrained(tuned_model)
    assert pipe.config.pflow.detail_norm
    torch.testing.assert_close(pipe.pflow.latent_norm.detail_gain.float(), gain, rtol=1e-3, atol=0)
    plain = UMFPipeline.from_pretrained(model)
    a = pipe("a person walks", num_people=1, seconds=1.0, seed=0)[0].joints
    b = plain("a person walks", num_people=1, seconds=1.0, seed=0)[0].joints
    assert np.isfinite(a).all() and not np.allclose(a, b)  # the gains change the samples


def test_the_vae_decoder_fine_tunes_alone_from_a_model(trained, tmp_path):
    """--init + train_vae.decoder_only: the VAE starts from the model's weights, its
    encoder (so every latent the flows know) stays bit-identical, the decoder trains."""
    from umf.checkpoint import read_weights

    root, _, _ = trained
    model = save_tiny_model(tmp_path / "source", seed=7)
    cfg = small_config()
    tuning = ["train_vae.decoder_only=true", "vae.w_root_vel=1.0", "train_vae.max_steps=2",
              "train_vae.warmup_steps=0"]  # fmt: skip
    for o in [*TINY, *tuning]:
        cfg = set_option(cfg, o)
    logs: list[str] = []
    with pytest.raises(UMFError, match="pass --init"):
        train_stage("vae", root / "corpus", tmp_path / "bad", cfg, Launch(progress=False))
    train_stage("vae", root / "corpus", tmp_path / "ft", cfg, Launch(progress=False),
                init=model, log=logs.append)  # fmt: skip
    assert any("starting from the weights" in m for m in logs)
    start, tuned = read_weights(model, "vae"), read_weights(tmp_path / "ft" / "vae" / "last", "vae")
    enc = ("in_proj", "encoder.", "adapter", "query_tokens", "feature_", "body_")  # + buffers
    assert all(torch.equal(tuned[k].float(), start[k].float()) for k in start if k.startswith(enc))
    assert any(not torch.allclose(tuned[k].float(), start[k].float())
               for k in start if k.startswith("decoder."))  # fmt: skip
    with pytest.raises(UMFError, match="only the VAE stage"):
        train_stage(
            "sflow",
            root / "corpus",
            tmp_path / "bad2",
            set_option(cfg, "train_sflow.decoder_only=true"),
            Launch(progress=False),
        )


def test_people_after_the_first_decode_with_the_reaction_root_fusion(trained):
    """Person 1's floor path is fused at vae.root_fusion, people 2..N at
    vae.reaction_root_fusion: changing one moves only its people."""
    _, model, _ = trained

    def raw(**vae) -> np.ndarray:
        pipe = UMFPipeline.from_pretrained(model)
        for k, v in vae.items():
            setattr(pipe.config.vae, k, v)
        return pipe(
            "two people walk", num_people=3, seconds=1.0, seed=0, fit=False, separate=False
        )[0].joints

    base = raw(root_fusion=0.005, reaction_root_fusion=0.005)
    react = raw(root_fusion=0.005, reaction_root_fusion=1e-4)
    first = raw(root_fusion=1e-4, reaction_root_fusion=0.005)
    assert np.array_equal(react[0], base[0]) and not np.allclose(react[1:], base[1:])
    assert np.array_equal(first[1:], base[1:]) and not np.allclose(first[0], base[0])


def test_prompts_are_respelled_into_the_captions_spelling(trained):
    """text.respell: "walks backward" is encoded as "walks backwards", so both give the
    same motion under one seed; without the pair they differ."""
    _, model, _ = trained
    pipe = UMFPipeline.from_pretrained(model)

    def joints(prompt: str) -> np.ndarray:
        return pipe(prompt, num_people=1, seconds=1.0, seed=0, fit=False)[0].joints

    pipe.config.text.respell = ("backward=backwards",)
    assert np.array_equal(joints("a person walks backward"), joints("a person walks backwards"))
    pipe.config.text.respell = ()
    assert not np.allclose(joints("a person walks backward"), joints("a person walks backwards"))


def test_reencoded_context_is_what_sflow_trained_on(trained, monkeypatch):
    """With sflow.reencode_context, S-Flow's context is the encoder's posterior mean of the
    people decoded so far, in person 1's re-centred first frame (as training crops are), and
    people 2..N come back into the scene's frame: person 1 is unchanged, the others move."""
    import torch

    from umf.representation import canonicalize_features, leader_frame, transform_features

    _, model, _ = trained
    prompt = dict(prompts="two people walk", num_people=3, seconds=1.0, seed=0,
                  fit=False, separate=False)  # fmt: skip
    pipe = UMFPipeline.from_pretrained(model)
    off = pipe(**prompt)[0]
    pipe.config.sflow.reencode_context = True
    contexts = []
    sample = pipe.sflow.sample

    def spy(prev, *a, **k):
        contexts.append(prev.clone())
        return sample(prev, *a, **k)

    monkeypatch.setattr(pipe.sflow, "sample", spy)
    on = pipe(**prompt)[0]
    assert np.array_equal(on.joints[0], off.joints[0])
    assert not np.allclose(on.joints[1:], off.joints[1:], atol=1e-3)
    feats = torch.from_numpy(on.features)
    tf = leader_frame(feats[0])
    with torch.no_grad():
        want1 = pipe._encode(canonicalize_features(feats[0])[None])
        want2 = pipe._encode(transform_features(feats[1], tf)[None])
    assert len(contexts) == 2 and contexts[1].shape[1] == 2
    assert torch.allclose(contexts[0][:, 0], want1, atol=1e-4)
    assert torch.allclose(contexts[1][:, 0], want1, atol=1e-4)
    assert torch.allclose(contexts[1][:, 1], want2, atol=1e-4)


def test_a_generated_person_1_starts_over_the_origin_with_pin_leader_start(trained):
    """vae.pin_leader_start: person 1's fused path moves (rigidly) to start where every
    training crop starts them; people 2..N stay where they were decoded. Off: the fused
    path's start is wherever the positions sit on average."""
    _, model, _ = trained

    def scene(pin: bool):
        pipe = UMFPipeline.from_pretrained(model)
        pipe.config.vae.pin_leader_start = pin
        pipe.config.vae.root_fusion = 1e-4  # trust the velocities: the start drifts
        return pipe("two people walk", num_people=2, seconds=1.0, seed=0, fit=False,
                    separate=False)[0].joints  # fmt: skip

    off, on = scene(False), scene(True)
    assert np.linalg.norm(off[0, 0, 0, [0, 2]]) > 0.01  # the test means something
    assert np.allclose(on[0, 0, 0, [0, 2]], 0.0, atol=1e-5)
    moved = off[0] - on[0]
    assert np.allclose(moved, moved[:1, :1], atol=1e-5) and np.allclose(moved[..., 1], 0.0)
    assert np.array_equal(on[1], off[1])


def test_pin_leader_start_leaves_react_scenes_unchanged(trained, bandai_clips):
    """In react mode person 1 is the user's actor, placed where they are: the pin must not
    move anybody, neither the actor nor the people placed beside them (whose warm start
    reads the actor's pace, which no rigid shift changes)."""
    _, model, _ = trained
    actor = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0][:61]

    def scene(pin: bool) -> np.ndarray:
        pipe = UMFPipeline.from_pretrained(model)
        pipe.config.vae.pin_leader_start = pin
        return pipe("two people bow to each other", num_people=3, actor=actor, seed=0,
                    fit=False, separate=False)[0].joints  # fmt: skip

    on = scene(True)
    assert np.allclose(on[0], actor[:60], atol=1e-5)
    assert np.array_equal(on, scene(False))
