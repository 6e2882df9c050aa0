"""Parts of the pipeline the end-to-end tests pass over (a mutation sample found them):
scene metadata, the error for non-finite latents, the default normaliser, the vocabulary a
saved model carries, moving the text encoder with the model."""

from __future__ import annotations

import pytest
import torch

from conftest import MODULE, FakeText, save_tiny_model, tiny_config
from umf.coverage import Vocabulary, embed
from umf.errors import UMFError
from umf.pipeline import UMFPipeline


@pytest.fixture(scope=MODULE)
def pipe(tmp_path_factory):
    model = save_tiny_model(tmp_path_factory.mktemp("parts") / "model", seed=2)
    return UMFPipeline.from_pretrained(model, text_encoder=FakeText())


def test_each_scene_records_its_sample_index(pipe):
    scenes = pipe(["a person waves", "a person waves", "a person bows"], num_people=2,
                  seconds=1.0, seed=3, sample_indices=[5, 0, 9])  # fmt: skip
    assert [s.meta["sample_index"] for s in scenes] == [5, 0, 9]


def test_non_finite_latents_are_a_one_line_error(pipe, monkeypatch):
    real = pipe.pflow.sample

    def broken(*args, **kwargs):
        z, n = real(*args, **kwargs)
        return torch.full_like(z, float("nan")), n

    monkeypatch.setattr(pipe.pflow, "sample", broken)
    message = r"^non-finite values \(NaN or inf\) in the sampled latents \(P-Flow"
    with pytest.raises(UMFError, match=message):
        pipe("a person waves", num_people=2, seconds=1.0, seed=0)


def test_a_built_pipeline_normalises_with_zero_mean_and_unit_scale():
    built = UMFPipeline.build(tiny_config(), text_encoder=FakeText())
    norm = built.normalizer
    assert torch.equal(norm.mean, torch.zeros(262)) and torch.equal(norm.std, torch.ones(262))


def test_a_saved_model_carries_its_vocabulary(pipe, tmp_path):
    phrases = ["a person waves.", "two people bow to each other."]
    pipe.vocabulary = Vocabulary(phrases, embed(pipe.text_encoder, phrases), "fake", 0.7,
                                 actions=["wave", "bow"])  # fmt: skip
    try:
        out = pipe.save_pretrained(tmp_path / "saved", name="tiny-saved")
    finally:
        pipe.vocabulary = None
    loaded = UMFPipeline.from_pretrained(out, text_encoder=FakeText())
    assert loaded.name == "tiny-saved"
    assert loaded.vocabulary.phrases == phrases and loaded.vocabulary.actions == ["wave", "bow"]
    assert loaded.coverage(["a person waves."])[0]["known"]


def test_moving_the_model_moves_its_text_encoder(pipe):
    moved = []

    class MovableText(FakeText):
        def to(self, device):
            moved.append(torch.device(device))
            return self

    built = UMFPipeline.build(tiny_config(), text_encoder=MovableText())
    assert built.to("cpu") is built
    assert moved == [torch.device("cpu")] and built.device == torch.device("cpu")
