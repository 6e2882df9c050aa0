import itertools
import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset

from conftest import BANDAI_FIXTURE
from umf.checkpoint import load_checkpoint, read_weights
from umf.config import TrainConfig
from umf.errors import UMFError
from umf.train import batching as B
from umf.train import datasets as D
from umf.train.loop import lr_at, train
from umf.train.metrics import read_metrics

TESTS = Path(__file__).resolve().parent
SRC = TESTS.parent / "src"


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """Tiny models: one thread avoids OpenMP spinning on a busy 2-core machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


class ToyData(Dataset):
    """y = sin(x A): a fixed function of random inputs."""

    def __init__(self, n: int = 40, seed: int = 0) -> None:
        g = torch.Generator().manual_seed(seed)
        self.x = torch.randn(n, 8, generator=g)
        a = torch.randn(8, 2, generator=torch.Generator().manual_seed(9)) / 8**0.5
        self.y = torch.sin(self.x @ a)

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> dict:
        return {"x": self.x[i], "y": self.y[i], "index": i}


class ToyStage:
    """An MLP with dropout and input noise (so the loop's RNG handling matters)."""

    def __init__(self, init_seed: int = 0, crash_at: int | None = None) -> None:
        torch.manual_seed(init_seed)
        self.net = nn.Sequential(nn.Linear(8, 32), nn.Tanh(), nn.Dropout(0.1), nn.Linear(32, 2))
        self.frozen = nn.Linear(2, 2).requires_grad_(False)
        self.crash_at = crash_at
        self.seen: list[int] = []

    def modules(self) -> dict[str, nn.Module]:
        return {"net": self.net, "frozen": self.frozen}

    def trainable(self) -> nn.Module:
        return self.net

    def training_step(self, batch: dict, step: int) -> dict[str, torch.Tensor]:
        if step == self.crash_at:
            raise RuntimeError("killed")
        self.seen += batch["index"].tolist()
        pred = self.net(batch["x"] + 0.05 * torch.randn_like(batch["x"]))
        mse = ((pred - batch["y"]) ** 2).mean()
        return {"total": mse, "mse": mse, "abs": (pred - batch["y"]).abs().mean()}

    def validation_step(self, batch: dict) -> dict[str, float]:
        return {"total": float(((self.net(batch["x"]) - batch["y"]) ** 2).mean())}


def toy_cfg(**kw) -> TrainConfig:
    base = dict(
        lr=1e-2, warmup_steps=3, max_steps=24, batch_size=8, log_every=4, val_every=8,
        ckpt_every=8, ema_decay=0.9, seed=3,
    )  # fmt: skip
    return TrainConfig(**{**base, **kw})


def toy_loaders(batch_size: int = 8):
    # two corpora of different sizes, alternating (epochs end at different steps)
    a = DataLoader(ToyData(40), batch_size=batch_size, shuffle=True, drop_last=True)
    b = DataLoader(ToyData(24, seed=1), batch_size=batch_size, shuffle=True, drop_last=True)
    val = DataLoader(ToyData(16, seed=2), batch_size=batch_size)
    return B.MixedBatches(a, b), val


def run(out: Path, stage: ToyStage, cfg: TrainConfig, resume: bool = False) -> dict:
    train_loader, val = toy_loaders(cfg.batch_size)
    return train(
        stage, train_loader, val, cfg, out, config={"model": "toy"}, resume=resume,
        progress=False, log=lambda s: None,
    )  # fmt: skip


def _params(stage: ToyStage) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in stage.net.parameters()])


def _rows(out: Path) -> list[tuple]:
    return [(r.step, r.split, r.name, r.value) for r in read_metrics(out / "metrics.csv")]


# --------------------------------------------------------------------- tests
def test_lr_schedule():
    cfg = TrainConfig(lr=1e-3, warmup_steps=10, max_steps=110)
    assert lr_at(0, cfg) == pytest.approx(1e-4)
    assert lr_at(9, cfg) == pytest.approx(1e-3)
    assert lr_at(60, cfg) == pytest.approx(5e-4)
    assert lr_at(110, cfg) == pytest.approx(0.0, abs=1e-12)
    lrs = [lr_at(s, cfg) for s in range(10, 111)]
    assert all(a >= b for a, b in itertools.pairwise(lrs))
    assert lr_at(0, TrainConfig(lr=1e-3, warmup_steps=0, max_steps=10)) == pytest.approx(1e-3)


def test_toy_training_learns_and_writes_outputs(tmp_path):
    stage = ToyStage()
    summary = run(tmp_path, stage, toy_cfg(max_steps=48, ckpt_every=16, val_every=16))
    assert summary["steps"] == 48 and summary["seconds_per_step"] > 0
    train_total = [v for s, sp, n, v in _rows(tmp_path) if sp == "train" and n == "total"]
    assert train_total[-1] < 0.7 * train_total[0]
    val = [v for s, sp, n, v in _rows(tmp_path) if sp == "val" and n == "total"]
    assert len(val) == 3 and summary["best_val"] == pytest.approx(min(val))
    for name in ("metrics.csv", "loss_curves.png", "last/format.json", "best/net.safetensors"):
        assert (tmp_path / name).exists(), name
    assert (tmp_path / "loss_curves.png").read_bytes()[:4] == b"\x89PNG"
    names = {n for _, _, n, _ in _rows(tmp_path)}
    assert {"total", "mse", "abs", "lr", "grad_norm"} <= names
    ck = load_checkpoint(tmp_path / "last", trainer_state=True)
    assert ck.step == 48 and ck.config == {"model": "toy"} and set(ck.weights) == {"net", "frozen"}
    # with EMA on, the checkpoint's module file holds the averaged weights
    ema = ck.ema["shadow"]["0.weight"]
    torch.testing.assert_close(ck.weights["net"]["0.weight"], ema)
    assert not torch.equal(ema, stage.net[0].weight.detach())
    with pytest.raises(UMFError, match="already has a checkpoint"):
        run(tmp_path, ToyStage(), toy_cfg())


def test_killed_and_resumed_run_equals_uninterrupted_run(tmp_path):
    cfg = toy_cfg()
    full = ToyStage()
    run(tmp_path / "full", full, cfg)

    with pytest.raises(RuntimeError, match="killed"):
        run(tmp_path / "cut", ToyStage(crash_at=19), cfg)  # last checkpoint: step 16
    assert load_checkpoint(tmp_path / "cut" / "last", trainer_state=True).step == 16
    resumed = ToyStage(init_seed=123)  # different init: everything must come from the checkpoint
    summary = run(tmp_path / "cut", resumed, cfg, resume=True)

    assert summary["steps"] == 24 and summary["resumed_from"] == 16
    diff = float((_params(full) - _params(resumed)).abs().max())
    print(f"resume max abs param diff {diff:.3g}")
    assert diff <= 1e-6, diff
    for name in ("net", "frozen"):
        a, b = read_weights(tmp_path / "full/last", name), read_weights(tmp_path / "cut/last", name)
        for k in a:
            torch.testing.assert_close(a[k], b[k], atol=1e-6, rtol=0)
    # the resumed run saw the same batches and logged the same curve
    assert full.seen[16 * 8 :] == resumed.seen
    assert _rows(tmp_path / "full") == _rows(tmp_path / "cut")


def test_resume_with_longer_schedule_continues(tmp_path):
    first = run(tmp_path, ToyStage(), toy_cfg(max_steps=12))
    assert first["steps"] == 12
    second = run(tmp_path, ToyStage(init_seed=7), toy_cfg(max_steps=24), resume=True)
    assert second["steps"] == 24 and second["steps_this_run"] == 12
    rows = _rows(tmp_path)
    steps = [s for s, sp, n, _ in rows if sp == "train" and n == "total"]
    assert steps == sorted(set(steps)) and steps[-1] == 24
    totals = [v for _, sp, n, v in rows if sp == "train" and n == "total"]
    assert totals[-1] < totals[0]
    assert all(math.isfinite(v) for v in totals)


def test_resume_without_checkpoint_starts_fresh(tmp_path):
    messages: list[str] = []
    train_loader, val = toy_loaders()
    summary = train(
        ToyStage(), train_loader, val, toy_cfg(max_steps=4, ema_decay=None), tmp_path / "new",
        resume=True, tensorboard=True, progress=False, log=messages.append,
    )  # fmt: skip
    assert summary["steps"] == 4 and summary["resumed_from"] is None
    assert any("starting from step 0" in m for m in messages)
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        assert any("tensorboard is not installed" in m for m in messages)
    else:
        assert (tmp_path / "new" / "tensorboard").exists()


def test_bad_config_and_stage(tmp_path):
    with pytest.raises(UMFError, match="val_every"):
        run(tmp_path / "a", ToyStage(), toy_cfg(val_every=0))
    with pytest.raises(UMFError, match="ema_decay"):
        run(tmp_path / "b", ToyStage(), toy_cfg(ema_decay=1.5))
    tiny = DataLoader(ToyData(4), batch_size=8, shuffle=True, drop_last=True)
    with pytest.raises(UMFError, match="yields no batch"):
        train(ToyStage(), tiny, None, toy_cfg(), tmp_path / "c", progress=False, log=print)


def test_real_corpus_mixed_batches(tmp_path):
    from umf.data.corpus import Corpus, PrepareConfig, prepare_corpus

    prep = PrepareConfig(train_scenes=8, val_scenes=2, test_scenes=2, test_groups=2)
    prepare_corpus(tmp_path / "c", {"bandai": BANDAI_FIXTURE}, prep, progress=False, log=print)
    corpus = Corpus.load(tmp_path / "c")
    norm = corpus.normalizer
    single = D.SingleMotionDataset(corpus, "train", norm, 10, 30, random_placement=True)
    scenes = D.SceneDataset(corpus, "train", norm, 10, 30)
    val = D.SceneDataset(corpus, "val", norm, 10, 30)

    class Linear:
        """Denoise features with one linear map: person 1 of scenes, or the single person."""

        def __init__(self) -> None:
            self.net = nn.Linear(262, 262)
            self.kinds: list[bool] = []

        def modules(self):
            return {"denoiser": self.net}

        def trainable(self):
            return self.net

        def _loss(self, batch):
            f = batch["features"][:, 0] if "people_mask" in batch else batch["features"]
            err = (self.net(f + 0.1 * torch.randn_like(f)) - f).pow(2).mean(-1)
            return (err * batch["mask"]).sum() / batch["mask"].sum()

        def training_step(self, batch, step):
            self.kinds.append("people_mask" in batch)
            return {"total": self._loss(batch)}

        def validation_step(self, batch):
            return {"total": float(self._loss(batch))}

    stage = Linear()
    loaders = B.MixedBatches(
        B.make_loader(single, 4, shuffle=True), B.make_loader(scenes, 4, shuffle=True)
    )
    cfg = TrainConfig(lr=1e-3, warmup_steps=2, max_steps=6, log_every=2, val_every=3, ckpt_every=3)
    summary = train(
        stage, loaders, B.make_loader(val, 2, shuffle=False), cfg, tmp_path / "run",
        normalizer=norm, progress=False, log=lambda s: None,
    )  # fmt: skip
    assert summary["steps"] == 6 and summary["best_val"] is not None
    assert stage.kinds == [False, True] * 3
    ck = load_checkpoint(tmp_path / "run" / "last")
    torch.testing.assert_close(ck.normalizer.mean, norm.mean)


DDP_SCRIPT = """
import json, sys
import torch
from torch.utils.data import DataLoader
sys.path.insert(0, {tests!r})
from test_train_loop import ToyData, ToyStage, toy_cfg
from umf.train.loop import train

torch.set_num_threads(1)
out = sys.argv[1]
stage = ToyStage()
train_loader = DataLoader(ToyData(32), batch_size=4, shuffle=True, drop_last=True)
val = DataLoader(ToyData(12, seed=2), batch_size=4)
cfg = toy_cfg(max_steps=4, batch_size=4, log_every=2, val_every=4, ckpt_every=4)
summary = train(stage, train_loader, val, cfg, out, accelerator="cpu", devices=2,
                strategy="ddp", progress=False, log=lambda s: None)
rank = torch.distributed.get_rank()
params = [p.detach().flatten().tolist() for p in stage.net.parameters()]
with open(f"{{out}}/rank{{rank}}.json", "w") as fh:
    json.dump({{"seen": stage.seen, "params": params, "steps": summary["steps"],
               "world": torch.distributed.get_world_size()}}, fh)
torch.distributed.barrier()  # rank 0 exits only once both ranks have written
"""


def test_ddp_two_processes_on_cpu(tmp_path):
    script = tmp_path / "ddp_run.py"
    script.write_text(textwrap.dedent(DDP_SCRIPT.format(tests=str(TESTS))))
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), str(TESTS)])}
    env.pop("LOCAL_RANK", None)
    proc = subprocess.run(  # two ranks; a busy 2-core machine takes minutes
        [sys.executable, str(script), str(out)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    r0 = json.loads((out / "rank0.json").read_text())
    r1 = json.loads((out / "rank1.json").read_text())
    assert r0["world"] == r1["world"] == 2 and r0["steps"] == r1["steps"] == 4
    # 4 steps x 4 items = each rank's whole shard of one epoch: disjoint halves of 32
    assert len(r0["seen"]) == len(r1["seen"]) == 16
    assert not set(r0["seen"]) & set(r1["seen"])
    assert set(r0["seen"]) | set(r1["seen"]) == set(range(32))
    # gradients were averaged: both replicas hold the same weights
    for a, b in zip(r0["params"], r1["params"], strict=True):
        torch.testing.assert_close(torch.tensor(a), torch.tensor(b), atol=1e-6, rtol=0)
    ck = load_checkpoint(out / "last", trainer_state=True)
    assert ck.step == 4 and ck.state["world_size"] == 2
    assert (out / "metrics.csv").exists() and (out / "best").exists()
    assert not list(out.glob(".*tmp*"))
