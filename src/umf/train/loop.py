"""A model-agnostic, step-based trainer on Lightning Fabric (one CPU to a GPU cluster).

A stage (VAE, P-Flow, S-Flow) only says which modules it has, which of them train and how
a batch becomes losses (:class:`Stage`); :func:`train` does the rest: devices and DDP,
AdamW with warmup + cosine, clipping, EMA, logging, validation, atomic checkpoints and
exact resumption.

Why resumption is exact: items are functions of (seed, epoch, index), samplers shuffle by
(seed, epoch) and skip what an epoch already consumed, and every step reseeds torch, numpy
and ``random`` from (seed, step, rank). A run killed after a checkpoint and resumed thus
takes the same batches and random draws as an uninterrupted run, on any number of ranks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import random
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from umf.checkpoint import (
    Checkpoint,
    find_checkpoint,
    load_checkpoint,
    load_first_good,
    previous_path,
    save_checkpoint,
)
from umf.config import TrainConfig
from umf.errors import UMFError
from umf.io import remove_stale_temporaries
from umf.representation import Normalizer
from umf.train.batching import MixedBatches, Stream, loaders_of, validation_loader
from umf.train.ema import EMA
from umf.train.metrics import CURVES_FILE, MetricsLog, plot_curves

LAST, BEST = "last", "best"
Log = Callable[[str], None]


class Stage(Protocol):
    """What :func:`train` needs from a model. Optional: ``on_checkpoint() -> dict | None``,
    called on rank 0 before each save; a returned dict is stored in the trainer state."""

    def modules(self) -> dict[str, nn.Module]:
        """Every module to checkpoint (trainable and frozen), by file name."""
        ...

    def trainable(self) -> nn.Module:
        """The module whose ``requires_grad`` parameters the optimiser updates."""
        ...

    def training_step(self, batch: Any, step: int) -> dict[str, Tensor]:
        """Losses of one batch; ``'total'`` is optimised, the rest are logged."""
        ...

    def validation_step(self, batch: Any) -> dict[str, float]:
        """Metrics of one batch (``'total'`` picks the best checkpoint)."""
        ...


# --------------------------------------------------------------------- schedule, seeds
def lr_at(step: int, cfg: TrainConfig) -> float:
    """Learning rate of update ``step`` (0-based): linear warmup, then cosine to 0 at max."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    span = max(cfg.max_steps - cfg.warmup_steps, 1)
    t = min((step - cfg.warmup_steps) / span, 1.0)
    return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * t))


def seed_all(*key: int) -> None:
    """Seed torch, numpy and ``random`` from a tuple of integers (one stream per key)."""
    words = np.random.SeedSequence([k % 2**63 for k in key]).generate_state(2)
    s = (int(words[0]) << 31) ^ int(words[1])
    random.seed(s)
    np.random.seed(s % 2**32)  # noqa: NPY002 (the global stream a stage may use)
    # not torch.manual_seed: it queues lazy seeds for every backend (~0.2 ms a step)
    torch.default_generator.manual_seed(s % 2**63)
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.manual_seed(s % 2**63)  # the current device: one rank, one GPU


def rng_states() -> dict[str, Any]:
    keys, pos, has_gauss, cached = np.random.get_state()[1:]  # noqa: NPY002
    out = {
        "torch": torch.get_rng_state(),
        "numpy": {"keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached": float(cached)},
        "python": random.getstate(),
    }  # fmt: skip
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        out["cuda"] = torch.cuda.get_rng_state_all()
    return out


def set_rng_states(states: Mapping[str, Any]) -> None:
    torch.set_rng_state(states["torch"].cpu())
    n = states["numpy"]
    np.random.set_state(  # noqa: NPY002
        ("MT19937", n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"])
    )
    random.setstate(states["python"])
    if "cuda" in states and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.cpu() for s in states["cuda"]])


@contextlib.contextmanager
def _forked_rng(device: torch.device) -> Iterator[None]:
    """Random draws inside (validation) leave the training streams untouched."""
    py, npy = random.getstate(), np.random.get_state()  # noqa: NPY002
    devices = [device] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        yield
    random.setstate(py)
    np.random.set_state(npy)  # noqa: NPY002


def _reduce_means(
    fabric: Any, sums: Mapping[str, Any], counts: Mapping[str, int]
) -> dict[str, float]:
    """Means over all ranks of per-key sums (keys may differ between ranks and batches)."""
    keys = sorted(sums)
    if fabric.world_size > 1:
        gathered: list[Any] = [None] * fabric.world_size
        torch.distributed.all_gather_object(gathered, keys)
        keys = sorted(set().union(*gathered))
    vec = torch.tensor(
        [float(sums.get(k, 0.0)) for k in keys] + [float(counts.get(k, 0)) for k in keys],
        dtype=torch.float64,
        device=fabric.device,
    )
    if fabric.world_size > 1:
        vec = fabric.all_reduce(vec, reduce_op="sum")
    n = len(keys)
    return {k: float(vec[i] / vec[n + i]) for i, k in enumerate(keys) if vec[n + i] > 0}


# --------------------------------------------------------------------- the run
class _StepModule(nn.Module):
    """Routes ``training_step`` through ``forward`` so DDP and autocast wrap all of it."""

    def __init__(self, stage: Stage) -> None:
        super().__init__()
        self.net = stage.trainable()
        self._stage = [stage]  # a list, so a Stage that is an nn.Module is not registered

    def forward(self, batch: Any, step: int) -> dict[str, Tensor]:
        return self._stage[0].training_step(batch, step)


@contextlib.contextmanager
def _eval_mode(modules: Sequence[nn.Module]) -> Iterator[None]:
    modes = [[(m, m.training) for m in mod.modules()] for mod in modules]
    for mod in modules:
        mod.eval()
    try:
        yield
    finally:
        for group in modes:
            for m, was in group:
                m.train(was)


def check_train_config(cfg: TrainConfig) -> None:
    """The optimisation settings a run cannot start without."""
    for name in ("max_steps", "log_every", "val_every", "ckpt_every", "batch_size"):
        if getattr(cfg, name) < 1:
            raise UMFError(f"train config: {name} must be >= 1, got {getattr(cfg, name)}")
    if cfg.warmup_steps < 0 or cfg.lr <= 0:
        raise UMFError("train config: need lr > 0 and warmup_steps >= 0")
    if cfg.ema_decay is not None and not 0.0 < cfg.ema_decay < 1.0:
        raise UMFError(f"train config: ema_decay must be in (0, 1), got {cfg.ema_decay}")


def _launch(accelerator: str, devices: int | str, num_nodes: int, strategy: str, precision: str):
    fabric = check_launch(accelerator, devices, num_nodes, strategy, precision)
    fabric.launch()
    return fabric


def check_launch(accelerator: str, devices: int | str, num_nodes: int, strategy: str,
                 precision: str) -> Any:  # fmt: skip
    """Lightning Fabric set up for these options, not launched (one-line errors): a run can
    say a bad ``--accelerator`` before it writes anything."""
    from lightning_fabric import Fabric

    # stages may leave parameters unused on some batches (per-dataset branches)
    strategy = "ddp_find_unused_parameters_true" if strategy == "ddp" else strategy
    try:
        fabric = Fabric(
            accelerator=accelerator, devices=devices, num_nodes=num_nodes,
            strategy=strategy, precision=precision,  # type: ignore[arg-type]
        )  # fmt: skip
    except Exception as exc:  # Fabric reports misconfiguration with several types
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UMFError(f"cannot set up training on {accelerator}: {msg}") from exc
    return fabric


@dataclasses.dataclass
class _Run:
    fabric: Any
    stage: Stage
    cfg: TrainConfig
    out: Path
    model: Any  # the Fabric-wrapped _StepModule
    optimizer: Any
    scheduler: torch.optim.lr_scheduler.LRScheduler
    ema: EMA | None
    streams: list[Stream]
    val_loaders: list[DataLoader]
    metrics: MetricsLog | None
    config: dict[str, Any]
    normalizer: Normalizer | None
    log: Log
    progress: bool = True
    step: int = 0
    start_step: int = 0
    best_val: float = math.inf
    best_step: int | None = None
    elapsed: float = 0.0  # training seconds of earlier runs (resume)
    train_seconds: float = 0.0
    last_train: dict[str, float] = dataclasses.field(default_factory=dict)
    last_val: dict[str, float] = dataclasses.field(default_factory=dict)
    _sums: dict[str, Any] = dataclasses.field(default_factory=dict)
    _counts: dict[str, int] = dataclasses.field(default_factory=dict)
    _t0: float = dataclasses.field(default_factory=time.perf_counter)

    @property
    def rank0(self) -> bool:
        return bool(self.fabric.is_global_zero)

    def seconds(self) -> float:
        return self.elapsed + time.perf_counter() - self._t0

    # ---------------------------------------------------------------- one step
    def train_step(self) -> None:
        stream = self.streams[self.step % len(self.streams)]
        batch = self.fabric.to_device(next(stream))
        seed_all(self.cfg.seed, self.fabric.global_rank, 0, self.step)
        self.optimizer.zero_grad(set_to_none=True)
        losses = self.model(batch, self.step)
        if "total" not in losses:
            raise UMFError("training_step must return a 'total' loss")
        self.fabric.backward(losses["total"])
        values = {k: v.detach().float() for k, v in losses.items()}
        if self.cfg.grad_clip and self.cfg.grad_clip > 0:
            norm = self.fabric.clip_gradients(
                self.model, self.optimizer, max_norm=self.cfg.grad_clip
            )
            values["grad_norm"] = norm.detach().float()
        values["lr"] = torch.tensor(self.optimizer.param_groups[0]["lr"])
        self.optimizer.step()
        self.scheduler.step()
        if self.ema is not None:
            self.ema.update()
        self.step += 1
        for k, v in values.items():
            self._sums[k] = self._sums.get(k, 0.0) + v
            self._counts[k] = self._counts.get(k, 0) + 1

    def flush_train(self, bar: tqdm) -> None:
        """Average the losses since the last flush over steps and ranks; log them."""
        if not self._counts:
            return
        means = _reduce_means(self.fabric, self._sums, self._counts)
        self._sums, self._counts = {}, {}
        if not math.isfinite(means.get("total", 0.0)):
            raise UMFError(
                f"training loss is not finite at step {self.step}; "
                f"the last good checkpoint is {self.out / LAST}"
            )
        self.last_train = means
        if self.rank0:
            assert self.metrics is not None
            self.metrics.add(self.step, "train", means, self.seconds())
            bar.set_postfix(loss=f"{means['total']:.4g}", lr=f"{means['lr']:.2e}")
            if bar.disable:
                self.log(f"step {self.step}: " + _fmt(means))

    # ---------------------------------------------------------------- validation
    def validate(self) -> dict[str, float]:
        modules = [*self.stage.modules().values(), self.stage.trainable()]
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        ema = self.ema.applied() if self.ema is not None else contextlib.nullcontext()
        with ema, _eval_mode(modules), torch.no_grad(), _forked_rng(self.fabric.device):
            seed_all(self.cfg.seed, self.fabric.global_rank, 1)
            for loader in self.val_loaders:
                for batch in loader:
                    with self.fabric.autocast():
                        out = self.stage.validation_step(self.fabric.to_device(batch))
                    for k, v in out.items():
                        sums[k] = sums.get(k, 0.0) + float(v)
                        counts[k] = counts.get(k, 0) + 1
        return _reduce_means(self.fabric, sums, counts)

    def run_validation(self) -> None:
        means = self.validate()
        self.last_val = means
        key = "total" if "total" in means else (sorted(means)[0] if means else None)
        improved = key is not None and means[key] < self.best_val
        if improved:
            self.best_val, self.best_step = means[key], self.step
        if self.rank0:
            assert self.metrics is not None
            self.metrics.add(self.step, "val", means, self.seconds())
            self.log(f"val @ {self.step}: " + _fmt(means) + ("  (best)" if improved else ""))
            plot_curves(self.metrics.rows, self.out / CURVES_FILE)
        if improved:
            self.save(BEST, with_optimizer=False)

    # ---------------------------------------------------------------- checkpoints
    def use_weights(self) -> dict[str, dict[str, Tensor]]:
        """Module state dicts with the EMA averages in place of the trainable weights."""
        swap = self.ema.by_id() if self.ema is not None else {}
        out = {}
        for name, module in self.stage.modules().items():
            sd = module.state_dict(keep_vars=True)
            out[name] = {k: swap.get(id(v), v).detach() for k, v in sd.items()}
        return out

    def state(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "best_val": self.best_val,
            "best_step": self.best_step,
            "elapsed": self.seconds(),
            "streams": [s.state_dict() for s in self.streams],
            "world_size": self.fabric.world_size,
            "train_config": dataclasses.asdict(self.cfg),
            "rng": rng_states(),
        }

    def save(self, name: str, with_optimizer: bool = True) -> None:
        """Rank 0 writes the checkpoint directory atomically; the others wait for it."""
        if self.rank0:
            hook = getattr(self.stage, "on_checkpoint", None)
            extra = hook() if callable(hook) else None
            save_checkpoint(
                self.out / name,
                self.use_weights(),
                config=self.config,
                normalizer=self.normalizer,
                state=self.state(),
                optimizer=self.optimizer.state_dict() if with_optimizer else None,
                scheduler=self.scheduler.state_dict() if with_optimizer else None,
                ema=self.ema.state_dict() if (self.ema is not None and with_optimizer) else None,
                extra={"stage": extra} if isinstance(extra, dict) else None,
                keep_previous=name == LAST,  # the previous good `last` survives as last.prev
            )
        self.fabric.barrier()

    def restore(self, ck: Checkpoint) -> None:
        """Continue from a checkpoint whose module weights are already loaded."""
        s = ck.state
        if ck.optimizer is None or ck.scheduler is None:
            raise UMFError(f"{ck.path}: no optimizer state, cannot resume from it")
        self.optimizer.load_state_dict(ck.optimizer)
        self.scheduler.load_state_dict(ck.scheduler)
        if self.ema is not None:
            if ck.ema is None:
                raise UMFError(f"{ck.path}: saved without EMA; cannot resume with ema_decay set")
            self.ema.load_state_dict(ck.ema)
        elif ck.ema is not None and "raw" in ck.ema:  # EMA switched off: go on from raw weights
            with torch.no_grad():
                for n, p in self.stage.trainable().named_parameters():
                    if n in ck.ema["raw"]:
                        p.copy_(ck.ema["raw"][n])
        self.step = self.start_step = int(s["step"])
        self.best_val = float(s.get("best_val", math.inf))
        self.best_step = s.get("best_step")
        self.elapsed = float(s.get("elapsed", 0.0))
        streams = s.get("streams", [])
        if len(streams) == len(self.streams):
            for stream, st in zip(self.streams, streams, strict=True):
                stream.load_state_dict(st)
        else:
            self.log("resume: different number of training loaders, data order restarts")
        if s.get("world_size") != self.fabric.world_size:
            self.log("resume: different number of ranks, data shards differ from the first run")
        if "rng" in s:
            set_rng_states(s["rng"])

    # ---------------------------------------------------------------- loop
    def fit(self) -> dict[str, Any]:
        cfg = self.cfg
        bar = tqdm(
            total=cfg.max_steps, initial=self.step, desc="train", unit="step",
            disable=not (self.rank0 and self.progress), dynamic_ncols=True,
        )  # fmt: skip
        self._t0 = time.perf_counter()
        try:
            while self.step < cfg.max_steps:
                t = time.perf_counter()
                self.train_step()
                self.train_seconds += time.perf_counter() - t
                bar.update(1)
                self.after_step(bar)
        finally:
            bar.close()
            if self.metrics is not None:
                self.metrics.close()
        return self.summary()

    def after_step(self, bar: tqdm) -> None:
        s, cfg = self.step, self.cfg
        end = s == cfg.max_steps
        validate = bool(self.val_loaders) and (s % cfg.val_every == 0 or end)
        ckpt = s % cfg.ckpt_every == 0 or end
        if s % cfg.log_every == 0 or end or validate or ckpt:
            self.flush_train(bar)
        if validate:
            self.run_validation()
        if ckpt:
            self.save(LAST)
            if self.rank0 and not self.val_loaders:
                assert self.metrics is not None
                plot_curves(self.metrics.rows, self.out / CURVES_FILE)

    def summary(self) -> dict[str, Any]:
        ran = self.step - self.start_step
        return {
            "steps": self.step,
            "steps_this_run": ran,
            "resumed_from": self.start_step or None,
            "seconds": round(time.perf_counter() - self._t0, 3),
            "seconds_per_step": self.train_seconds / ran if ran else None,
            "train": self.last_train,
            "val": self.last_val,
            "best_val": self.best_val if math.isfinite(self.best_val) else None,
            "best_step": self.best_step,
            "out_dir": str(self.out),
        }


def _fmt(values: Mapping[str, float]) -> str:
    return "  ".join(f"{k} {v:.4g}" for k, v in values.items())


# --------------------------------------------------------------------- entry point
def train(
    stage: Stage,
    train_loader: DataLoader | MixedBatches,
    val_loader: DataLoader | MixedBatches | None,
    cfg: TrainConfig,
    out_dir: str | Path,
    *,
    config: Mapping[str, Any] | None = None,
    normalizer: Normalizer | None = None,
    accelerator: str = "cpu",
    devices: int | str = 1,
    num_nodes: int = 1,
    strategy: str = "auto",
    precision: str = "32-true",
    resume: bool = False,
    progress: bool = True,
    tensorboard: bool = False,
    log: Log = print,
) -> dict[str, Any]:
    """Train ``stage`` for ``cfg.max_steps`` optimiser steps; returns a summary dict.

    ``out_dir`` receives ``last/`` (every ``ckpt_every`` steps and at the end), ``best/``
    (lowest validation 'total'), ``metrics.csv`` and ``loss_curves.png``. ``config`` (the
    model config) and ``normalizer`` are stored in every checkpoint. ``resume=True``
    continues from ``out_dir/last`` when it exists. ``cfg.batch_size`` is per device:
    the loaders are re-sharded across ranks here. Checkpoints and resumption assume
    ``out_dir`` is on a file system every rank sees.
    """
    check_train_config(cfg)
    fabric = _launch(accelerator, devices, num_nodes, strategy, precision)
    out = Path(out_dir)
    say: Log = log if fabric.is_global_zero else (lambda s: None)
    found = find_checkpoint(out / LAST) or find_checkpoint(previous_path(out / LAST))
    if found is not None and not resume:
        raise UMFError(f"{out} already has a checkpoint; pass resume or choose another out dir")
    if resume and found is None:
        say(f"resume: no checkpoint in {out}, starting from step 0")
    if fabric.is_global_zero:
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(out)  # half-written curves of a run killed with -9
    fabric.barrier()
    run = _build(fabric, stage, train_loader, val_loader, cfg, out, found, say, tensorboard)
    run.config, run.normalizer, run.progress = dict(config or {}), normalizer, progress
    n = sum(p.numel() for g in run.optimizer.param_groups for p in g["params"])
    say(
        f"training {n:,} parameters on {fabric.world_size} x {fabric.device.type}, "
        f"step {run.step} -> {cfg.max_steps}"
    )
    return run.fit()


def _build(
    fabric: Any,
    stage: Stage,
    train_loader: DataLoader | MixedBatches,
    val_loader: DataLoader | MixedBatches | None,
    cfg: TrainConfig,
    out: Path,
    found: Path | None,
    say: Log,
    tensorboard: bool,
) -> _Run:
    """Modules on the device, (resumed) weights, optimiser, scheduler, EMA, data streams."""
    modules = stage.modules()
    for m in modules.values():
        fabric.to_device(m)
    ck = None
    if found is not None:  # the newest `last`, else the one it replaced (warned about)
        candidates = [out / LAST, previous_path(out / LAST)]
        ck = load_first_good(
            candidates, lambda p: load_checkpoint(p, modules, trainer_state=True), say
        )
    trainable = stage.trainable()
    trainable.train()
    params = [p for p in trainable.parameters() if p.requires_grad]
    if not params:
        raise UMFError("the stage has no trainable parameters")
    opt = torch.optim.AdamW(
        params, lr=cfg.lr, betas=tuple(cfg.betas), weight_decay=cfg.weight_decay
    )
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_at(s, cfg) / cfg.lr)
    model, opt = fabric.setup(_StepModule(stage), opt)
    ema = EMA(trainable, cfg.ema_decay) if cfg.ema_decay is not None else None
    rank, world = fabric.global_rank, fabric.world_size
    streams = [
        Stream(lo, seed=cfg.seed + 1_000_003 * i, rank=rank, world_size=world)
        for i, lo in enumerate(loaders_of(train_loader))
    ]
    if not streams:
        raise UMFError("no training loader")
    sizes = [s.loader.batch_size for s in streams]
    if cfg.batch_size not in sizes:
        say(f"note: training loaders use batch sizes {sizes}, cfg.batch_size is {cfg.batch_size}")
    vals = [validation_loader(lo, cfg.seed, rank, world) for lo in loaders_of(val_loader)]
    resume_step = ck.step if ck is not None else None
    metrics = (
        MetricsLog(out, resume_step=resume_step, tensorboard=tensorboard, log=say)
        if fabric.is_global_zero
        else None
    )
    run = _Run(
        fabric, stage, cfg, out, model, opt, sched, ema, streams, vals, metrics, {}, None, say
    )
    if ck is not None:
        run.restore(ck)
        say(f"resumed from {ck.path} at step {run.step}")
    return run
