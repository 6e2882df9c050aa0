"""Shared fixtures: the bundled real Bandai clips (data/bandai-sample)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

FIXTURES = Path(__file__).parent / "fixtures"
BANDAI_FIXTURE = Path(__file__).resolve().parents[1] / "data" / "bandai-sample"
SHARED_BANDAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"

# mutmut forks a worker per mutant from a process that has run the tests: an OpenMP pool
# started there deadlocks the children (every such mutant "timed out"), so one thread there
torch.set_num_threads(1 if "MUTANT_UNDER_TEST" in os.environ else 2)


def _shared(scope: str):
    """A fixture scope that is ``scope`` except in mutmut's stats run, where it is per test.

    mutmut learns which tests cover a function by crediting every call to the test running
    when it happens; a module fixture's calls would go to the first test that builds it, and
    a mutant of those functions would never run the later tests (issue 39)."""

    def decide(fixture_name: str, config) -> str:
        return "function" if os.environ.get("MUTANT_UNDER_TEST") == "stats" else scope

    return decide


MODULE = _shared("module")
SESSION = _shared("session")

# The end-to-end tests (a model trained from scratch, the bundled model in every format)
# take 8-60 s a run; under mutmut they run only for the pipeline's mutants, so a mutant
# elsewhere is scored by its own module's tests alone: a lower bound on what `make test`
# catches (results/mutation/README.md says so)
END_TO_END = {"test_pipeline.py": ("umf.pipeline.",), "test_reroll.py": ("umf.pipeline.",),
              "test_exports_agree.py": ("umf.pipeline.",)}  # fmt: skip


def mutation_scope(items: list, mutant: str) -> tuple[list, list]:
    """(kept, dropped) test items for a run against ``mutant`` (``module.x_fn__mutmut_N``;
    anything else, such as mutmut's "stats" run or no mutant, keeps every test)."""
    if not mutant.startswith("umf."):
        return list(items), []
    kept, dropped = [], []
    for item in items:
        owners = END_TO_END.get(Path(str(item.fspath)).name)
        (kept if owners is None or mutant.startswith(owners) else dropped).append(item)
    return kept, dropped


def pytest_collection_modifyitems(config, items) -> None:
    kept, dropped = mutation_scope(items, os.environ.get("MUTANT_UNDER_TEST", ""))
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = kept


def load_script(name: str):
    """A module of ``scripts/`` or ``research/`` (not packages), imported from its file for
    testing."""
    import importlib.util

    root = Path(__file__).resolve().parents[1]
    path = root / "scripts" / f"{name}.py"
    if not path.exists():
        path = root / "research" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


@pytest.fixture(scope=SESSION)
def bandai_clips():
    from umf.data.bandai import load_bandai

    return list(load_bandai(BANDAI_FIXTURE))


@pytest.fixture(scope=SESSION)
def actors(bandai_clips):
    """The bundled clips as scene-composer actors (person 1 of each clip)."""
    from umf.data.scenes import Actor

    return [
        Actor.from_joints(c.id, c.joints[0], c.meta["content"], c.meta["style"])
        for c in bandai_clips
    ]


@pytest.fixture(scope=SESSION)
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


class FakeText:
    """A fast stand-in for MiniLM (same width): fixed random token states per prompt."""

    dim = 384
    device = torch.device("cpu")
    identity = "fake-text"
    name = "fake"

    def encode(self, texts: list[str]):
        import zlib

        from umf.text import TextFeatures

        gens = [torch.Generator().manual_seed(zlib.crc32(t.encode())) for t in texts]
        lengths = [1 + len(t.split()) for t in texts]
        width = max(lengths)
        tokens = torch.zeros(len(texts), width, self.dim)
        mask = torch.zeros(len(texts), width, dtype=torch.bool)
        for i, (g, n) in enumerate(zip(gens, lengths, strict=True)):
            tokens[i, :n] = torch.randn(n, self.dim, generator=g)
            mask[i, :n] = True
        return TextFeatures(tokens, mask, tokens.sum(1) / mask.sum(1, keepdim=True))


def tiny_config():
    from umf.config import set_option, small_config

    cfg = small_config()
    for o in TINY_MODEL:
        cfg = set_option(cfg, o)
    return cfg


def save_tiny_model(out: Path, seed: int = 0, person_prompts: bool = False) -> Path:
    """An untrained tiny UMF model directory (what `umf train export` writes), in a second.

    ``person_prompts``: both flows take per-person prompts, through a random (not zero)
    projection, so an own prompt changes what they make."""
    from umf.checkpoint import save_checkpoint
    from umf.config import set_option
    from umf.pipeline import UMFPipeline
    from umf.representation import Normalizer

    torch.manual_seed(seed)
    cfg = tiny_config()
    if person_prompts:
        for o in ("pflow.denoiser.person_text=true", "sflow.denoiser.person_text=true"):
            cfg = set_option(cfg, o)
    pipe = UMFPipeline.build(cfg, text_encoder=FakeText())
    for flow in (pipe.pflow, pipe.sflow) if person_prompts else ():
        torch.nn.init.normal_(flow.net.person_proj.weight, std=0.5)
    norm = Normalizer(torch.zeros(262), torch.full((262,), 0.1))
    modules = {"vae": pipe.vae, "pflow": pipe.pflow, "sflow": pipe.sflow}
    return save_checkpoint(out, modules, config=cfg.to_dict(), normalizer=norm)


@pytest.fixture
def fake_text(monkeypatch):
    """Model loading builds FakeText instead of MiniLM (seconds per load saved)."""
    import umf.text

    monkeypatch.setattr(umf.text, "build_text_encoder", lambda *a, **k: FakeText())
