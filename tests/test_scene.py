"""The one motion container (umf.scene.Scene), the exports registry, save_pretrained and
the public imports."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from conftest import FakeText, save_tiny_model
from umf.errors import UMFError
from umf.scene import Scene


def test_public_imports():
    from umf import Scene as S
    from umf import UMFPipeline
    from umf.pipeline import Scene as PipelineScene
    from umf.pipeline import UMFPipeline as P

    assert S is PipelineScene is Scene and UMFPipeline is P
    # the checkpoint format moved out of training; the old name is the same module
    import umf.checkpoint
    import umf.train.checkpoint

    assert umf.train.checkpoint is umf.checkpoint


def test_inference_does_not_import_training():
    code = ("import sys, umf.pipeline, umf.scene; "
            "print(any(m.startswith('umf.train') for m in sys.modules))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_scene_from_joints_is_fitted(real_joints):
    raw = real_joints.numpy()[None, :40]
    scene = Scene(raw, None, "walk", 30.0)
    assert scene.bodies is not None and scene.joints.dtype == np.float32
    assert np.array_equal(scene.raw_joints, raw)
    assert np.abs(scene.joints - raw).max() < 1e-5  # rigid input: unchanged
    part = scene.frames(30, 10)
    assert part.num_frames == 20 and part.bodies.num_frames == 20
    assert np.array_equal(part.joints, scene.joints[:, 10:30])
    loose = Scene(raw, None, "walk", 30.0, fit=False)
    assert loose.bodies is None and loose.rigid().bodies is not None
    assert loose.frames(5).bodies is None
    with pytest.raises(ValueError):
        Scene(raw[0], None, "walk", 30.0)
    with pytest.raises(ValueError):
        Scene(raw, None, "walk", 30.0, bodies=scene.bodies.frames(5))


def test_save_every_format_names_and_atomicity(real_joints, tmp_path):
    scene = Scene(np.stack([real_joints.numpy()[:30]] * 2), None, "Two people walk!", 30.0)
    paths = scene.save(tmp_path, "npz,bvh,smpl,humanml3d")
    assert sorted(p.name for p in paths) == sorted([
        "two-people-walk.npz", "two-people-walk-p1.bvh", "two-people-walk-p2.bvh",
        "two-people-walk-p1.smpl.npz", "two-people-walk-p2.smpl.npz",
        "two-people-walk-p1.humanml3d.npz", "two-people-walk-p2.humanml3d.npz",
    ])  # fmt: skip
    assert scene.save(tmp_path / "x.npz", ["npz"]) == [tmp_path / "x.npz"]
    # a scene of fewer people under the same name drops the extra per-person files
    one = Scene(real_joints.numpy()[None, :30], None, "Two people walk!", 30.0)
    one.save(tmp_path, "bvh,smpl")
    assert not (tmp_path / "two-people-walk-p2.bvh").exists()
    assert not (tmp_path / "two-people-walk-p2.smpl.npz").exists()
    with pytest.raises(UMFError, match="unknown format"):
        scene.save(tmp_path, "fbx")
    (tmp_path / "blocked.glb").mkdir()
    with pytest.raises(UMFError):
        scene.save(tmp_path / "blocked", "npz,glb")
    assert not (tmp_path / "blocked.npz").exists()  # all or nothing


def test_npz_reads_back_as_the_same_scene(real_joints, tmp_path):
    from umf.data.motion_file import load_motion

    scene = Scene(real_joints.numpy()[None, :30], None, "a walk", 30.0)
    path = scene.save_npz(tmp_path / "a.npz")
    back = load_motion(path)
    assert isinstance(back, Scene) and back.text == "a walk"
    assert np.abs(back.joints - scene.joints).max() < 1e-5


@pytest.mark.parametrize("generated", [True, False])
def test_npz_holds_every_documented_array(real_joints, tmp_path, generated):
    """The keys exports/npz.py documents, float32, with their values: a generated scene
    (features, seed, coverage) and a motion file's (none of them; seed -1; float64 joints)."""
    import json

    from umf.version import __version__

    joints = np.stack([real_joints.numpy()[:20], real_joints.numpy()[:20] + 2.0])
    features = np.random.default_rng(0).normal(size=(2, 20, 262)) if generated else None
    meta = {"coverage": {"known": 0.75, "nearest": "a walk"}} if generated else {}
    dtype = np.float32 if generated else np.float64
    scene = Scene(joints.astype(dtype), features, "two walks", 30.0,
                  seed=12 if generated else None, model="m-1" if generated else "",
                  meta=meta)  # fmt: skip
    data = np.load(scene.save_npz(tmp_path / "s.npz"))
    arrays = ["joints", "raw_joints", "offsets", "rotations", "root", "fps"]
    optional = ["features", "coverage"] if generated else []
    assert set(data.files) == {*arrays, "text", "seed", "model_version", "umf_version",
                               *optional}  # fmt: skip
    for key in arrays + optional[:1]:
        assert data[key].dtype == np.float32, key
    bodies = scene.rigid().bodies
    np.testing.assert_array_equal(data["joints"], scene.joints.astype(np.float32))
    np.testing.assert_allclose(data["raw_joints"], scene.raw_joints, atol=1e-6)
    np.testing.assert_allclose(data["offsets"], bodies.offsets, atol=1e-6)
    np.testing.assert_allclose(data["rotations"], bodies.rotations, atol=1e-6)
    np.testing.assert_allclose(data["root"], bodies.root, atol=1e-6)
    assert float(data["fps"]) == 30.0 and str(data["text"]) == "two walks"
    assert int(data["seed"]) == (12 if generated else -1)
    assert str(data["model_version"]) == scene.model and str(data["umf_version"]) == __version__
    if generated:
        np.testing.assert_allclose(data["features"], features, atol=1e-6)
        assert json.loads(str(data["coverage"])) == meta["coverage"]


def test_save_pretrained_round_trip(tmp_path, fake_text):
    from umf.pipeline import UMFPipeline

    model = save_tiny_model(tmp_path / "tiny")
    pipe = UMFPipeline.from_pretrained(model, text_encoder=FakeText())
    out = pipe.save_pretrained(tmp_path / "copy", name="tiny-copy")
    again = UMFPipeline.from_pretrained(out, text_encoder=FakeText())
    assert again.name == "tiny-copy"
    for a, b in zip(pipe.vae.state_dict().values(), again.vae.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    s1 = pipe("two people wave", num_people=2, seconds=1.0, seed=3)[0]
    s2 = again("two people wave", num_people=2, seconds=1.0, seed=3)[0]
    assert np.allclose(s1.joints, s2.joints, atol=1e-6)


def test_pipeline_fit_flag(tmp_path, fake_text):
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(save_tiny_model(tmp_path / "tiny"))
    fitted = pipe("a person waves", num_people=2, seconds=1.0, seed=1)[0]
    raw = pipe("a person waves", num_people=2, seconds=1.0, seed=1, fit=False)[0]
    assert np.allclose(fitted.raw_joints, raw.joints, atol=1e-6)
    assert raw.bodies is None and fitted.bodies is not None
    assert fitted.meta["floor"] == 0.0
    assert fitted.joints[..., 1].min() >= -1e-5  # nobody in the floor


def test_cli_writes_smpl_and_humanml3d(tmp_path, fake_text, monkeypatch, capsys):
    """`umf generate --format smpl,humanml3d` (in process, the tiny model): every file it
    names exists; an unknown format is one line, exit 1 (the bad value) or 2, no file."""
    from umf.cli.main import run

    model = save_tiny_model(tmp_path / "tiny")
    out = tmp_path / "gen"
    with pytest.raises(SystemExit) as code:
        run(["generate", "two people wave", "--people", "2", "--seconds", "1", "--format",
             "smpl,humanml3d", "--out", str(out), "--model", str(model)])  # fmt: skip
    assert code.value.code == 0
    printed = [line.removeprefix("wrote ") for line in capsys.readouterr().out.splitlines()]
    names = sorted(p.split("/")[-1] for p in printed)
    assert names == [
        "00-two-people-wave-p1.humanml3d.npz",
        "00-two-people-wave-p1.smpl.npz",
        "00-two-people-wave-p2.humanml3d.npz",
        "00-two-people-wave-p2.smpl.npz",
    ]
    with np.load(out / "00-two-people-wave-p2.smpl.npz") as z:
        assert z["poses"].shape == (30, 156)
    with pytest.raises(SystemExit) as code:
        run(["generate", "x", "--format", "smpl,fbx", "--out", str(tmp_path / "bad"),
             "--model", str(model)])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code.value.code == 1 and len(err) == 1 and err[0].startswith("umf: error:")
    assert not (tmp_path / "bad").exists()


def test_dataset_clip_becomes_a_scene(bandai_clips, tmp_path):
    clip = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001")
    scene = clip.to_scene()
    assert scene.meta["id"] == clip.id and scene.text == clip.captions[0]
    assert np.abs(scene.joints - clip.joints).max() < 1e-5
    assert [p.name for p in scene.save(tmp_path / "bow", "bvh")] == ["bow-p1.bvh"]
