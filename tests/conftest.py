"""Shared fixtures: the bundled real Bandai clips (data/bandai-sample)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

FIXTURES = Path(__file__).parent / "fixtures"
BANDAI_FIXTURE = Path(__file__).resolve().parents[1] / "data" / "bandai-sample"
SHARED_BANDAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"

torch.set_num_threads(2)


@pytest.fixture(scope="session")
def bandai_clips():
    from umf.data.bandai import load_bandai

    return list(load_bandai(BANDAI_FIXTURE))


@pytest.fixture(scope="session")
def real_joints(bandai_clips):
    """One real walking clip, (T, 22, 3) float64 torch, for maths tests."""
    clip = next(c for c in bandai_clips if c.id == "dataset-1_walk_normal_001")
    return torch.from_numpy(clip.joints[0]).double()
