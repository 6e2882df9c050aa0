"""Per-scene random streams, chunking, finiteness, all-or-nothing scene files, devices,
checkpoint fallback and `data prepare` recovery (issue 11)."""

from __future__ import annotations

import os
import re
import time

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE, FakeText, save_tiny_model
from umf.errors import UMFError
from umf.pipeline import UMFPipeline
from umf.writer import COMPLETE, TMP_PREFIX, clean_stale, write_scene_files

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def pipe(tmp_path_factory):
    model = save_tiny_model(tmp_path_factory.mktemp("tiny") / "model")
    return UMFPipeline.from_pretrained(model, text_encoder=FakeText())


def _call(pipe, prompts, **kw):
    kw = {"num_people": 3, "seconds": 1.0, "seed": 7, **kw}
    return pipe(prompts, **kw)


# ------------------------------------------------------------------ random streams
def test_a_scene_does_not_depend_on_its_batch(pipe):
    alone = _call(pipe, ["a person walks"])[0].joints
    with_other = _call(pipe, ["a person walks", "two people bow to each other slowly"])[0]
    copies = _call(pipe, ["a person walks"] * 3)
    assert np.allclose(with_other.joints, alone, atol=1e-4)
    assert np.allclose(copies[0].joints, alone, atol=1e-4)
    assert [s.meta["sample_index"] for s in copies] == [0, 1, 2]
    assert not np.allclose(copies[1].joints, alone, atol=1e-2)  # another sample, not a copy
    again = _call(pipe, ["b", "a person walks"], sample_indices=[0, 1])[1]
    assert np.allclose(again.joints, copies[1].joints, atol=1e-4)  # sample 1, wherever it is
    first = _call(pipe, ["a person walks", "b"], sample_indices=[1, 0])[0]  # sample 1 first:
    assert np.allclose(first.joints, copies[1].joints, atol=1e-4)  # its index picks its noise,
    assert not np.allclose(first.joints, alone, atol=1e-2)  # not its place in the call


def test_chunking_does_not_change_scenes(pipe, monkeypatch):
    whole = _call(pipe, ["a", "b", "c"])
    import umf.pipeline

    monkeypatch.setattr(umf.pipeline, "chunk_size", lambda people, frames: 1)
    chunked = _call(pipe, ["a", "b", "c"])
    for x, y in zip(whole, chunked, strict=True):
        assert np.allclose(x.joints, y.joints, atol=1e-4)


def test_seed_none_is_recorded_and_reproduces(pipe):
    s = _call(pipe, ["a"], seed=None)[0]
    assert isinstance(s.seed, int)
    assert np.allclose(_call(pipe, ["a"], seed=s.seed)[0].joints, s.joints, atol=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"num_people": 2.5}, "--people must be an integer"),
        ({"num_people": True}, "--people must be an integer"),
        ({"prompts": None}, "the prompt must be a string"),
        ({"prompts": ["a", 3]}, "every prompt must be a string"),
        ({"prompts": []}, "the prompt is empty"),
        ({"seconds": float("inf")}, "--seconds must be a finite number"),
        ({"seed": -1}, "--seed must be between"),
        ({"guidance": float("nan")}, "--guidance must be a finite number"),
        ({"pflow_steps": [4, 2, 2]}, "--steps needs 2 count(s)"),
        ({"sflow_steps": 0}, "--sflow-steps must be between 1"),
        ({"sample_indices": [0, 1]}, "2 sample indices for 1 prompts"),
        ({"actor": np.zeros((40, 22, 3))}, "not a body"),
        ({"actor": [[0.0]]}, "must be a numpy array"),
    ],
)
def test_python_api_rejects_before_sampling(pipe, monkeypatch, kwargs, message):
    def boom(*a, **k):
        raise AssertionError("sampling ran")

    monkeypatch.setattr(pipe.pflow, "sample", boom)
    monkeypatch.setattr(pipe.sflow, "sample", boom)
    kwargs = {"prompts": "a person walks", **kwargs}
    with pytest.raises(UMFError, match=re.escape(message)):
        pipe(kwargs.pop("prompts"), **kwargs)


def test_non_finite_model_output_is_an_error(pipe, monkeypatch):
    monkeypatch.setattr(pipe.normalizer, "std", torch.full((262,), float("nan")))
    with pytest.raises(UMFError, match=r"non-finite values .* decoded motion"):
        _call(pipe, ["a"])


# ------------------------------------------------------------------ scene files
def test_scene_files_are_all_or_nothing(pipe, tmp_path, monkeypatch):
    scene = _call(pipe, ["a"])[0]
    stem = tmp_path / "out{i}" / "00-a"  # braces in the directory are not a pattern
    written = write_scene_files(scene, stem, ["npz", "bvh", "glb"])
    assert sorted(p.name for p in written) == sorted(p.name for p in stem.parent.iterdir())
    assert len(written) == 5  # npz, glb, one BVH per person
    before = {p.name: p.read_bytes() for p in stem.parent.iterdir()}

    other = _call(pipe, ["a"], seed=8, num_people=2)[0]

    def broken(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr("umf.exports.gltf.write", broken)  # the GLB format's writer
    with pytest.raises(OSError):
        write_scene_files(other, stem, ["npz", "bvh", "glb"])
    assert {p.name: p.read_bytes() for p in stem.parent.iterdir()} == before  # old set whole
    monkeypatch.undo()
    write_scene_files(other, stem, ["npz", "bvh", "glb"])
    names = sorted(p.name for p in stem.parent.iterdir())
    assert names == ["00-a-p1.bvh", "00-a-p2.bvh", "00-a.glb", "00-a.npz"]  # no stale p3


def test_non_finite_scene_is_never_written(pipe, tmp_path):
    scene = _call(pipe, ["a"])[0]
    scene.joints[0, 0, 0, 0] = np.nan
    with pytest.raises(UMFError, match="non-finite"):
        write_scene_files(scene, tmp_path / "o" / "s", ["npz"])
    assert not (tmp_path / "o").exists()


def test_stale_temporaries_are_rolled_forward_or_back(tmp_path):
    dead = 2**22 + 12345  # above the default pid_max: no such process
    done = tmp_path / f"{TMP_PREFIX}{dead}-aaaa"
    done.mkdir()
    (done / "s.npz").write_text("new")
    (done / COMPLETE).touch()
    half = tmp_path / f"{TMP_PREFIX}{dead}-bbbb"
    half.mkdir()
    (half / "t.npz").write_text("half")
    live = tmp_path / f"{TMP_PREFIX}{os.getppid()}-cccc"  # a running process's: kept
    live.mkdir()
    old = tmp_path / ".s.gif.x1y2.tmp"
    old.write_text("old")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    (tmp_path / "s.npz").write_text("old")
    clean_stale(tmp_path)
    assert (tmp_path / "s.npz").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s.npz", live.name])


# ------------------------------------------------------------------ devices
DEVICES = ["cpu", "meta"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture
def generator_spy(monkeypatch):
    """Every draw with a generator must use one on the device it fills."""
    wrong: list[str] = []
    for name in ("randn", "rand", "randint"):
        real = getattr(torch, name)

        def spy(*args, _real=real, _name=name, **kw):
            g, dev = kw.get("generator"), torch.device(kw.get("device") or "cpu")
            if g is not None and g.device.type != dev.type:
                wrong.append(f"{_name}: generator on {g.device}, tensor on {dev}")
            return _real(*args, **kw)

        monkeypatch.setattr(torch, name, spy)
    return wrong


def _fresh(device: str) -> UMFPipeline:
    from conftest import tiny_config

    torch.manual_seed(0)
    return UMFPipeline.build(tiny_config(), text_encoder=FakeText()).to(device)


def _latent_batch(pipe: UMFPipeline, device: str) -> dict:
    p, r = pipe.vae.latent_shape
    return {
        "z": torch.randn(4, 3, p, r).to(device),
        "people_mask": torch.tensor([[1, 1, 0], [1, 1, 1]] * 2, dtype=torch.bool, device=device),
        "dataset": torch.ones(4, dtype=torch.long, device=device),
        "captions": ["a", "b", "c", "d"],
    }


def _stages(pipe: UMFPipeline) -> tuple:
    from umf.text import TextFeatureCache
    from umf.train.stages import PFlowStage, SFlowStage

    cache = TextFeatureCache(FakeText())
    return (PFlowStage(pipe.config, pipe.vae, cache, pipe.pflow),
            SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow))  # fmt: skip


@pytest.mark.parametrize("device", DEVICES)
def test_generators_are_made_on_the_model_device(device, monkeypatch):
    """The pipeline's per-scene generators and the training stages' generators live on the
    model's device (none on `meta`, which has no values: the model cannot run there)."""
    pipe = _fresh(device)
    seen = []

    def record(*args, generator=None, **kw):
        seen.append(generator)
        raise StopIteration

    monkeypatch.setattr(pipe.pflow, "sample", record)
    with pytest.raises(StopIteration):
        pipe(["a", "b"], num_people=2, seconds=1.0, seed=0)
    gens = seen[0]
    assert len(gens) == 2
    for g in gens:
        assert g is None if device == "meta" else g.device.type == device
    for stage in _stages(pipe):
        g = stage.generator.on(torch.device(device))
        assert g is None if device == "meta" else g.device.type == device
    batch = _latent_batch(pipe, device)
    _, prev_mask, w, _, _ = _stages(pipe)[1]._inputs(batch)  # random reacting person
    assert prev_mask.device.type == w.device.type == device


@pytest.mark.parametrize("device", [d for d in DEVICES if d != "meta"])
def test_sampling_and_a_training_step_run_on_device(device, generator_spy):
    """Generation and one training step of both flow stages, every random draw checked."""
    pipe = _fresh(device)
    scene = pipe("a person walks", num_people=2, seconds=1.0, seed=0)[0]
    assert np.isfinite(scene.joints).all()
    batch = _latent_batch(pipe, device)
    for stage in _stages(pipe):
        loss = stage.training_step(batch, 0)["total"]
        assert loss.device.type == device and torch.isfinite(loss)
        loss.backward()
    assert not generator_spy


# ------------------------------------------------------------------ checkpoints
def test_corrupt_last_falls_back_to_the_previous_one(tmp_path):
    from torch import nn

    from umf.checkpoint import load_checkpoint, load_first_good, save_checkpoint

    net = nn.Linear(3, 2)
    for step in (1, 2):
        save_checkpoint(tmp_path / "last", {"net": net}, state={"step": step},
                        optimizer={"x": 1}, keep_previous=True)  # fmt: skip
    assert (tmp_path / "last.prev").is_dir()
    (tmp_path / "last" / "trainer_state.pt").write_bytes(b"torn")
    warnings: list[str] = []
    ck = load_first_good(
        [tmp_path / "last", tmp_path / "last.prev"],
        lambda p: load_checkpoint(p, {"net": net}, trainer_state=True),
        warnings.append,
    )
    assert ck.step == 1 and len(warnings) == 1 and "trainer_state.pt" in warnings[0]
    (tmp_path / "last.prev" / "net.safetensors").write_bytes(b"torn")
    with pytest.raises(UMFError, match=r"trainer_state\.pt"):  # none good: the newest's error
        load_first_good([tmp_path / "last", tmp_path / "last.prev"],
                        lambda p: load_checkpoint(p, {"net": net}, trainer_state=True),
                        warnings.append)  # fmt: skip


# ------------------------------------------------------------------ data prepare
def test_prepare_rerun_keeps_skipped_and_a_killed_run_keeps_the_last_corpus(tmp_path, monkeypatch):
    import shutil

    from umf.data import corpus as C

    src = tmp_path / "bandai"
    shutil.copytree(BANDAI_FIXTURE, src)
    data = next(src.rglob("*.bvh")).parent
    (data / "dataset-1_broken_normal_001.bvh").write_text("HIERARCHY\nROOT x {\n")
    counts = {"train_scenes": 4, "val_scenes": 1, "test_scenes": 1, "test_groups": 1}
    out = tmp_path / "corpus"
    first = C.prepare_corpus(out, {"bandai": src}, C.PrepareConfig(**counts), progress=False,
                             log=lambda s: None)  # fmt: skip
    second = C.prepare_corpus(out, {"bandai": src}, C.PrepareConfig(**counts), progress=False,
                              log=lambda s: None)  # fmt: skip
    assert second["sources"][0]["reused_cache"]
    assert first["skipped"] and second["skipped"] == first["skipped"]

    real = C.write_json_atomic

    def dies_after_scenes(path, obj):
        real(path, obj)
        if path.name == "scenes.json":
            raise KeyboardInterrupt

    monkeypatch.setattr(C, "write_json_atomic", dies_after_scenes)
    with pytest.raises(KeyboardInterrupt):
        C.prepare_corpus(
            out, {"bandai": src}, C.PrepareConfig(**{**counts, "seed": 9}), progress=False,
            log=lambda s: None,
        )  # fmt: skip
    # the corpus that worked is still there, whole: the killed run's files never replaced it
    kept = C.Corpus.load(out)
    assert kept.manifest["seed"] == first["seed"] and kept.manifest["created"] == second["created"]
    assert not list(out.glob(".staging-*"))
