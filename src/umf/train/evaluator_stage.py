"""Training the contrastive text-motion evaluators (``umf train evaluator``).

Two evaluators are trained on the corpus, each with :func:`umf.train.loop.train`:
``interaction`` on the two-person scenes, ``single`` on the single-person clips. Both see
raw features (the evaluator normalises internally with the corpus statistics), random
crops and mirroring (with side words swapped) in training, and whole scenes/clips (up to
``evaluator.max_frames``) in validation, in a fixed shuffled order so that each
validation batch is one retrieval group of 96 as in the protocol. Captions shared by two
items of a batch (and the same scene twice) are not used as negatives of each other.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import Dataset

from umf.config import TrainConfig, UMFConfig
from umf.data.corpus import Corpus
from umf.errors import UMFError
from umf.eval.evaluator import (
    KINDS,
    MotionTextEvaluator,
    build_text_source,
    clip_loss,
    evaluator_config_dict,
    init_clip_tables,
    same_pairs,
)
from umf.eval.metrics import r_precision
from umf.text import TextFeatureCache
from umf.train.batching import make_loader
from umf.train.datasets import SceneDataset, SingleMotionDataset

GROUP = 96  # the protocol's retrieval group (validation batch size)


class EvaluatorStage:
    """:class:`umf.train.loop.Stage` of one evaluator: CLIP loss on (motion, caption)."""

    name = "evaluator"

    def __init__(self, evaluator: MotionTextEvaluator, group: int = GROUP):
        self.evaluator = evaluator
        self.group = group

    def modules(self) -> dict[str, nn.Module]:
        return {"evaluator": self.evaluator}

    def trainable(self) -> nn.Module:
        return self.evaluator

    def _embed(self, batch: dict[str, Any]) -> tuple[Tensor, Tensor, Tensor]:
        ev = self.evaluator
        feats = batch["features"]
        if feats.dim() == 4 and feats.shape[1] != ev.num_people:
            raise UMFError(f"batch has {feats.shape[1]} people, evaluator {ev.num_people}")
        m, t = ev(feats, batch["mask"], ev.text_inputs(batch["captions"]))
        return m, t, same_pairs(batch["captions"], batch.get("ids")).to(m.device)

    def training_step(self, batch: dict[str, Any], step: int) -> dict[str, Tensor]:
        m, t, same = self._embed(batch)
        loss = clip_loss(m, t, same)
        with torch.no_grad():
            hit = (m @ t.T).argmax(dim=1) == torch.arange(len(m), device=m.device)
        scale = self.evaluator.latent_scale.detach()[0]
        return {"total": loss, "batch_top1": hit.float().mean(), "latent_scale": scale}

    @torch.no_grad()
    def validation_step(self, batch: dict[str, Any]) -> dict[str, float]:
        m, t, same = self._embed(batch)
        out = {"total": float(clip_loss(m, t, same))}
        if len(m) == self.group:  # only complete groups, as the protocol counts them
            tops = r_precision(t.cpu().numpy(), m.cpu().numpy(), group=self.group, top_k=3)
            out |= {f"r_precision_top{k + 1}": v for k, v in enumerate(tops)}
        return out


class Shuffled(Dataset):
    """A fixed, seeded permutation of a dataset (validation groups mix all kinds of items)."""

    def __init__(self, dataset: Any, seed: int = 0) -> None:
        self.dataset = dataset
        self.order = np.random.default_rng(seed).permutation(len(dataset)).tolist()
        self.collate = dataset.collate

    def __len__(self) -> int:
        return len(self.order)

    def __getitem__(self, index: int) -> Any:
        return self.dataset[self.order[index]]


def evaluator_loaders(corpus: Corpus, kind: str, t: TrainConfig, max_frames: int, group: int):
    """(train, val) loaders of raw features: crops for training, whole items for validation."""

    def dataset(split: str, lo: int, hi: int):
        train = split == "train"  # only training crops are mirrored and respelled
        aug = dict(mirror=train, respell=train and t.respell_captions, seed=t.seed)
        if kind == "interaction":
            return SceneDataset(corpus, split, None, lo, hi, max_people=2, **aug)
        return SingleMotionDataset(corpus, split, None, lo, hi, **aug)

    hi = min(t.max_frames, max_frames)
    train_ds = dataset("train", min(t.min_frames, hi), hi)
    val_ds = Shuffled(dataset("val", max_frames, max_frames), seed=t.seed)
    train = make_loader(train_ds, t.batch_size, shuffle=True, num_workers=t.num_workers,
                        seed=t.seed)  # fmt: skip
    val = make_loader(val_ds, group, shuffle=False, num_workers=t.num_workers)
    return train, val


@contextlib.contextmanager
def flush_denormals() -> Iterator[None]:
    """Denormal floats (tiny Adam second moments) slow CPU steps several-fold; flush them."""
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def train_evaluators(
    corpus_dir: Path,
    run_dir: Path,
    cfg: UMFConfig,
    launch: Any,
    *,
    kinds: Sequence[str] = ("interaction", "single"),
    resume: bool = False,
    max_steps: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """Train the evaluators of ``kinds`` into ``RUN/evaluator/<kind>/``; summaries by kind."""
    from umf.train.loop import train
    from umf.train.run import corpus_captions

    for kind in kinds:
        if kind not in KINDS:
            raise UMFError(f"unknown evaluator kind {kind!r} (choose {', '.join(KINDS)})")
    corpus = Corpus.load(corpus_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg.save_yaml(run_dir / "config.yaml")
    ecfg, t = cfg.evaluator, cfg.train_evaluator
    if max_steps is not None:
        t = TrainConfig(**{**vars(t), "max_steps": max_steps})
    source, sizes = build_text_source(ecfg, corpus.root / "text-cache")
    if isinstance(source, TextFeatureCache):  # frozen token states: encode every caption once
        captions = corpus_captions(corpus, respell=t.respell_captions)
        for i in range(0, len(captions), 256):
            source.encode(captions[i : i + 256])
    out: dict[str, dict[str, Any]] = {}
    with flush_denormals():
        for kind in kinds:
            torch.manual_seed(t.seed)
            model = MotionTextEvaluator(ecfg, kind, **sizes)
            if ecfg.text_encoder == "clip-tokens":
                init_clip_tables(model, ecfg.text_path)
            model.set_normalizer(corpus.normalizer)
            model.attach_text(source)
            train_loader, val_loader = evaluator_loaders(corpus, kind, t, ecfg.max_frames, GROUP)
            n = sum(p.numel() for p in model.parameters() if p.requires_grad)
            log(f"training the {kind} evaluator: {n:,} parameters")
            out[kind] = train(
                EvaluatorStage(model), train_loader, val_loader, t, run_dir / "evaluator" / kind,
                config=evaluator_config_dict(model), normalizer=corpus.normalizer,
                accelerator=launch.accelerator, devices=launch.devices,
                num_nodes=launch.num_nodes, strategy=launch.strategy,
                precision=launch.precision, resume=resume, progress=launch.progress,
                tensorboard=launch.tensorboard, log=log,
            )  # fmt: skip
    return out
