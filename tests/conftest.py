"""Shared fixtures: the bundled real Bandai clips (data/bandai-sample)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

FIXTURES = Path(__file__).parent / "fixtures"
BANDAI_FIXTURE = Path(__file__).resolve().parents[1] / "data" / "bandai-sample"
SHARED_BANDAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"

torch.set_num_threads(2)


def prepare_fixture_corpus(out: Path, **scenes: int) -> Path:
    """A small real corpus from the committed Bandai clips (``scenes``: PrepareConfig counts)."""
    from umf.data.corpus import PrepareConfig, prepare_corpus

    prepare_corpus(out, {"bandai": BANDAI_FIXTURE}, PrepareConfig(**scenes), progress=False,
                   log=lambda s: None)  # fmt: skip
    return out


@pytest.fixture(scope="module")
def one_thread():
    """Tiny models: one thread avoids OpenMP spinning on a busy 2-core machine (10-100x)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def bandai_clips():
    from umf.data.bandai import load_bandai

    return list(load_bandai(BANDAI_FIXTURE))


@pytest.fixture(scope="session")
def actors(bandai_clips):
    """The bundled clips as scene-composer actors (person 1 of each clip)."""
    from umf.data.scenes import Actor

    return [
        Actor.from_joints(c.id, c.joints[0], c.meta["content"], c.meta["style"])
        for c in bandai_clips
    ]


@pytest.fixture(scope="session")
def real_joints(bandai_clips):
    """One real walking clip, (T, 22, 3) float64 torch, for maths tests."""
    clip = next(c for c in bandai_clips if c.id == "dataset-1_walk_normal_001")
    return torch.from_numpy(clip.joints[0]).double()


# A tiny UMF (every stage a few thousand parameters) for end-to-end and ablation tests.
TINY_MODEL = [
    "vae.d_model=32", "vae.num_layers=3", "vae.ff_dim=64", "vae.num_tokens=4",
    "vae.latent_dim=8", "vae.max_frames=120",
    "pflow.denoiser.d_model=32", "pflow.denoiser.num_layers=3", "pflow.denoiser.ff_dim=64",
    "pflow.denoiser.text_width=32", "pflow.denoiser.text_heads=2", "pflow.denoiser.text_ff_dim=64",
    "pflow.steps=[4,2]",
    "sflow.denoiser.d_model=32", "sflow.denoiser.num_layers=3", "sflow.denoiser.ff_dim=64",
    "sflow.denoiser.text_width=32", "sflow.denoiser.text_heads=2", "sflow.denoiser.text_ff_dim=64",
    "sflow.context_ff_dim=32", "sflow.steps=3",
]  # fmt: skip
