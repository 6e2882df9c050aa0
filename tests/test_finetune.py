"""`umf train finetune`: a released model taught a new library, every stage from its weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE, FakeText, save_tiny_model
from test_mocap import _two_person_library

SHORT = ("max_steps=2", "batch_size=4", "val_every=2", "ckpt_every=2", "warmup_steps=1",
         "max_frames=60", "min_frames=30", "latent_passes=1")  # fmt: skip
STEPS = [f"train_{s}.{k}" for s in ("vae", "pflow", "sflow") for k in SHORT]


@pytest.fixture
def library_corpus(tmp_path):
    from umf.data.corpus import PrepareConfig, mocap_sources, prepare_corpus

    (tmp_path / "lib").mkdir()
    lib = _two_person_library(tmp_path / "lib", lengths=(70, 70))
    sources = {"bandai": BANDAI_FIXTURE, **mocap_sources([lib])}
    cfg = PrepareConfig(train_scenes=12, val_scenes=4, test_scenes=4, test_groups=2,
                        val_fraction=0.0, test_fraction=0.0)  # fmt: skip
    prepare_corpus(tmp_path / "c", sources, cfg, progress=False, log=lambda s: None)
    return tmp_path / "c"


def test_finetune_teaches_every_stage_and_exports_a_model_with_its_vocabulary(
    tmp_path, library_corpus, monkeypatch, one_thread
):
    import umf.text
    from umf.checkpoint import read_weights
    from umf.pipeline import UMFPipeline
    from umf.representation import Normalizer
    from umf.train.run import Launch, finetune

    monkeypatch.setattr(umf.text, "build_text_encoder", lambda *a, **k: FakeText())
    source = save_tiny_model(tmp_path / "source", seed=3)
    logs: list[str] = []
    model = finetune(source, library_corpus, tmp_path / "run", STEPS, Launch(progress=False),
                     log=logs.append)  # fmt: skip
    assert any("on this run's fine-tuned VAE" in m for m in logs)
    for stage in ("vae", "pflow", "sflow"):
        before, after = read_weights(source, stage), read_weights(model, stage)
        assert before.keys() == after.keys()
        assert any(not torch.equal(before[k].float(), after[k].float()) for k in before), stage
        assert (tmp_path / "run" / stage / "done.json").exists()
    # the model's feature statistics, not the new corpus's: its VAE was trained with them
    kept = Normalizer.load(model / "normalizer.safetensors")
    assert torch.allclose(kept.std, Normalizer.load(source / "normalizer.safetensors").std)
    assert not torch.allclose(
        kept.std, Normalizer.load(library_corpus / "normalizer.safetensors").std
    )
    pipe = UMFPipeline.from_pretrained(model)
    assert "Two people meet." in pipe.vocabulary.phrases
    (scene,) = pipe("Two people meet.", num_people=2, seconds=1.0, fit=False)
    assert scene.meta["coverage"]["known"] and np.isfinite(scene.joints).all()
    # a resumed fine-tune skips the finished stages
    again: list[str] = []
    finetune(source, library_corpus, tmp_path / "run", [], Launch(progress=False), resume=True,
             log=again.append)  # fmt: skip
    assert sum("already fine-tuned" in m for m in again) == 3


def test_real_takes_repeat_in_scene_batches(library_corpus):
    from umf.data.corpus import Corpus
    from umf.train.datasets import SceneDataset

    corpus = Corpus.load(library_corpus)
    once = SceneDataset(corpus, "train", corpus.normalizer)
    many = SceneDataset(corpus, "train", corpus.normalizer, real_repeats=5)
    takes = lambda ds: sum(kind == "clip" for kind, *_ in ds.items)  # noqa: E731
    assert takes(once) == 1 and takes(many) == 5
    assert len(many) - len(once) == 4
    ids = {many[i]["id"]: many[i]["start"] for i in range(len(many)) if many.items[i][0] == "clip"}
    assert len(ids) == 1
    starts = {many[i]["start"] for i in range(len(many)) if many.items[i][0] == "clip"}
    assert len(starts) > 1  # each repeat draws its own crop


def test_restating_the_body_statistics_keeps_the_vae_function(one_thread):
    """New body-frame statistics, absorbed by the projections: encoder means and decoded
    features unchanged for clips of whole tokens, and the buffers hold the new ones."""
    from conftest import tiny_config
    from umf.body_frame import BODY_DIM
    from umf.models.vae import MotionVAE
    from umf.representation import Normalizer

    torch.manual_seed(0)
    cfg = tiny_config().vae
    vae = MotionVAE(cfg).eval()
    vae.set_normalizers(
        Normalizer(torch.randn(262) * 0.1, torch.rand(262) + 0.5),
        Normalizer(torch.randn(BODY_DIM) * 0.1, torch.rand(BODY_DIM) + 0.5),
    )
    k = cfg.frames_per_token
    x = torch.randn(3, 10 * k, 262)
    mask = torch.ones(3, 10 * k, dtype=torch.bool)
    mu, _ = vae.encode(x, mask)
    out = vae.decode(mu, mask)
    new = Normalizer(torch.randn(BODY_DIM), torch.rand(BODY_DIM) * 3 + 0.2)
    vae.restate_body(new)
    mu2, _ = vae.encode(x, mask)
    assert torch.allclose(mu2, mu, atol=1e-4)
    assert torch.allclose(vae.decode(mu2, mask), out, atol=1e-3 * float(out.abs().max()))
    assert torch.equal(vae.body_std, new.std) and torch.equal(vae.body_mean, new.mean)


def test_a_stage_left_out_keeps_its_weights_and_its_training_options(
    tmp_path, library_corpus, monkeypatch, one_thread
):
    """`--stages pflow`: the VAE and S-Flow come from the model as they were, and so do
    their training options in the exported config (the fine-tune defaults are the P-Flow's
    only: a model card reading them must see how those stages were trained)."""
    import json

    import umf.text
    from umf.checkpoint import read_weights
    from umf.train.run import Launch, finetune

    monkeypatch.setattr(umf.text, "build_text_encoder", lambda *a, **k: FakeText())
    source = save_tiny_model(tmp_path / "source", seed=3)
    steps = [o for o in STEPS if o.startswith("train_pflow.")]
    model = finetune(source, library_corpus, tmp_path / "run", steps, Launch(progress=False),
                     stages=("pflow",), log=lambda m: None)  # fmt: skip
    for stage in ("vae", "sflow"):
        before, after = read_weights(source, stage), read_weights(model, stage)
        assert all(torch.equal(before[k].to(after[k].dtype), after[k]) for k in before), stage
    was, now = (json.loads((m / "config.json").read_text()) for m in (source, model))
    assert now["train_vae"] == was["train_vae"] and now["train_sflow"] == was["train_sflow"]
    assert now["train_pflow"]["lr"] == 0.0001 and now["train_pflow"]["max_steps"] == 2
