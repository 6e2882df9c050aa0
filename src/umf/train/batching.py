"""Batches for training: padding and masks for items of any length (one person or a
scene), a sampler that shards an epoch across ranks, and a source that mixes two loaders."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, IterableDataset, RandomSampler, Sampler

from umf.errors import UMFError
from umf.representation import (
    FEATURE_DIM,
)


# --------------------------------------------------------------------- batching
def _meta(items: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "lengths": torch.tensor([it["length"] for it in items], dtype=torch.long),
        "captions": [it["caption"] for it in items],
        # each person's own caption ("" = none): single items one, scenes one per person
        "person_captions": [list(it.get("person_captions", [])) for it in items],
        "dataset": torch.tensor([it["dataset"] for it in items], dtype=torch.long),
        "ids": [it["id"] for it in items],
    }


def collate_single(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Pad to the batch's longest crop: features (B, T, 262), mask (B, T) True on frames."""
    t = max(it["features"].shape[0] for it in items)
    feats = torch.zeros(len(items), t, FEATURE_DIM)
    mask = torch.zeros(len(items), t, dtype=torch.bool)
    for i, it in enumerate(items):
        n = it["features"].shape[0]
        feats[i, :n] = it["features"]
        mask[i, :n] = True
    return {"features": feats, "mask": mask, **_meta(items)}


def collate_scenes(items: list[dict[str, Any]]) -> dict[str, Any]:
    """Pad time and people: features (B, P, T, 262), mask (B, T), people_mask (B, P)."""
    t = max(it["features"].shape[1] for it in items)
    p = max(it["features"].shape[0] for it in items)
    feats = torch.zeros(len(items), p, t, FEATURE_DIM)
    mask = torch.zeros(len(items), t, dtype=torch.bool)
    people = torch.zeros(len(items), p, dtype=torch.bool)
    for i, it in enumerate(items):
        n_p, n_t = it["features"].shape[:2]
        feats[i, :n_p, :n_t] = it["features"]
        mask[i, :n_t] = True
        people[i, :n_p] = True
    num_people = torch.tensor([it["num_people"] for it in items], dtype=torch.long)
    return {
        "features": feats,
        "mask": mask,
        "people_mask": people,
        "num_people": num_people,
        **_meta(items),
    }


class ShardedSampler(Sampler[int]):
    """Seeded, epoch-keyed shuffling, sharded by rank, resumable mid-epoch.

    Like ``DistributedSampler`` (padding so every rank gets the same count), plus
    ``start``: the number of this rank's indices of the current epoch to skip, so a
    resumed run continues an epoch without loading the skipped items.
    """

    def __init__(
        self,
        num_items: int,
        *,
        shuffle: bool,
        seed: int = 0,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        if num_items <= 0:
            raise UMFError("cannot sample from an empty dataset")
        self.num_items, self.shuffle, self.seed = num_items, shuffle, seed
        self.rank, self.world_size = rank, world_size
        self.epoch, self.start = 0, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def indices(self) -> np.ndarray:
        """This rank's indices of the current epoch (before skipping ``start``)."""
        n = self.num_items
        order = (
            np.random.default_rng([self.seed, self.epoch]).permutation(n)
            if self.shuffle
            else np.arange(n)
        )
        total = math.ceil(n / self.world_size) * self.world_size
        return np.resize(order, total)[self.rank :: self.world_size]

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices()[self.start :].tolist())

    def __len__(self) -> int:
        return max(math.ceil(self.num_items / self.world_size) - self.start, 0)


def usable_workers(num_workers: int) -> int:
    """At most one loader worker per CPU this process may use: a config written on a
    16-core GPU machine (``num_workers`` 9) then fine-tuned on a laptop must not fork 9."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(0, min(num_workers, cpus or 1))


def make_loader(
    dataset: Dataset,
    batch_size: int,
    *,
    shuffle: bool,
    num_workers: int = 0,
    drop_last: bool | None = None,
    seed: int = 0,
) -> DataLoader:
    """A DataLoader with the dataset's own collate function (train: shuffle, drop_last).

    ``batch_size`` is per device; the trainer re-shards the loader across ranks.
    """
    return DataLoader(
        dataset,
        batch_size=batch_size,
        shuffle=shuffle,
        num_workers=usable_workers(num_workers),
        collate_fn=getattr(dataset, "collate", None),
        drop_last=shuffle if drop_last is None else drop_last,
        generator=torch.Generator().manual_seed(seed),
    )


class MixedBatches:
    """Alternate whole batches from several loaders (SPEC 6: single- and multi-person).

    The trainer takes batch ``step % len(loaders)`` from an endless, resumable stream of
    each loader. Iterating directly yields one batch of each in turn, restarting a loader
    that runs out, until every loader has been through at least once.
    """

    def __init__(self, *loaders: DataLoader) -> None:
        if not loaders:
            raise UMFError("MixedBatches needs at least one loader")
        self.loaders = list(loaders)

    def __len__(self) -> int:
        return len(self.loaders) * max(len(lo) for lo in self.loaders)

    def __iter__(self) -> Iterator[Any]:
        its = [iter(lo) for lo in self.loaders]
        done = [False] * len(its)
        while True:
            for i, lo in enumerate(self.loaders):
                try:
                    batch = next(its[i])
                except StopIteration:
                    done[i] = True
                    if all(done):
                        return
                    its[i] = iter(lo)
                    batch = next(its[i], None)
                    if batch is None:
                        raise UMFError(f"loader {i} of MixedBatches yields no batch") from None
                yield batch


# --------------------------------------------------------------------- data streams
def with_sampler(loader: DataLoader, sampler: ShardedSampler, seed: int) -> DataLoader:
    """The same loader (batch size, collate, workers) drawing indices from ``sampler``."""
    if isinstance(loader.dataset, IterableDataset) or loader.batch_size is None:
        raise UMFError("train() needs DataLoaders over map-style datasets with a batch_size")
    workers = loader.num_workers
    return DataLoader(
        loader.dataset,
        batch_size=loader.batch_size,
        sampler=sampler,
        num_workers=workers,
        collate_fn=loader.collate_fn,
        pin_memory=loader.pin_memory,
        drop_last=loader.drop_last,
        timeout=loader.timeout,
        worker_init_fn=loader.worker_init_fn,
        multiprocessing_context=loader.multiprocessing_context if workers else None,
        generator=torch.Generator().manual_seed(seed),
        prefetch_factor=loader.prefetch_factor if workers else None,
        # workers are restarted each epoch so they see the dataset's new epoch
        persistent_workers=False,
    )


class Stream:
    """An endless, resumable iterator over one loader: (epoch, batches consumed) is its state."""

    def __init__(self, loader: DataLoader, *, seed: int, rank: int, world_size: int) -> None:
        shuffle = isinstance(loader.sampler, RandomSampler)
        n = len(loader.dataset)  # type: ignore[arg-type]
        self.sampler = ShardedSampler(
            n, shuffle=shuffle, seed=seed, rank=rank, world_size=world_size
        )
        self.loader = with_sampler(loader, self.sampler, seed)
        self.epoch, self.consumed = 0, 0
        self._it: Iterator[Any] | None = None

    def _begin(self) -> None:
        self.sampler.set_epoch(self.epoch)
        self.sampler.start = self.consumed * int(self.loader.batch_size or 1)
        set_epoch = getattr(self.loader.dataset, "set_epoch", None)
        if callable(set_epoch):
            set_epoch(self.epoch)
        self._it = iter(self.loader)

    def __next__(self) -> Any:
        for _ in range(2):
            if self._it is None:
                self._begin()
            try:
                batch = next(self._it)  # type: ignore[arg-type]
            except StopIteration:
                self._it, self.epoch, self.consumed = None, self.epoch + 1, 0
                continue
            self.consumed += 1
            return batch
        raise UMFError(
            "a training loader yields no batch (dataset smaller than batch_size with drop_last?)"
        )

    def state_dict(self) -> dict[str, int]:
        return {"epoch": self.epoch, "consumed": self.consumed}

    def load_state_dict(self, state: Mapping[str, int]) -> None:
        self.epoch, self.consumed, self._it = int(state["epoch"]), int(state["consumed"]), None


def validation_loader(loader: DataLoader, seed: int, rank: int, world_size: int) -> DataLoader:
    """Each rank validates its own shard, in order, the same items every time."""
    n = len(loader.dataset)  # type: ignore[arg-type]
    sampler = ShardedSampler(n, shuffle=False, seed=seed, rank=rank, world_size=world_size)
    return with_sampler(loader, sampler, seed)


def loaders_of(source: DataLoader | MixedBatches | None) -> list[DataLoader]:
    if source is None:
        return []
    return list(source.loaders) if isinstance(source, MixedBatches) else [source]
