"""Latent banks: the frozen VAE's latents of many random crops, computed once.

P-Flow and S-Flow train on latents of a *frozen* VAE. Encoding every batch again costs
more than the flow step itself on a CPU, so each flow stage first encodes ``passes``
epochs of random crops (each pass draws new crops, mirrors and captions) and then
trains on the bank. On a GPU the bank is cheap to build and changes nothing else.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from umf.config import MULTI_PERSON
from umf.train.batching import usable_workers


@torch.no_grad()
def build_bank(
    vae: torch.nn.Module,
    dataset: Any,
    passes: int,
    batch_size: int = 64,
    progress: bool = True,
    desc: str = "latents",
    device: str | torch.device = "cpu",
    num_workers: int = 0,
) -> dict[str, Any]:
    """Encode ``passes`` epochs of ``dataset`` (single or scene items) with ``vae``.

    Returns ``z`` (N, P, p, r) posterior means, ``people_mask`` (N, P), ``dataset`` (N,),
    ``captions`` (N) and ``person_captions`` (N lists, each person's own), on the CPU.
    Single-person items have P = 1. ``device`` runs the
    encoder there (the VAE is moved back to where it was afterwards).
    """
    home = next(vae.parameters()).device
    vae.eval().to(device)
    zs, masks, datasets, captions, own = [], [], [], [], []
    total = passes * len(dataset)
    bar = tqdm(total=total, desc=desc, unit="crop", disable=not progress)
    for epoch in range(passes):
        dataset.set_epoch(epoch)
        loader = DataLoader(dataset, batch_size=batch_size, shuffle=False,
                            collate_fn=dataset.collate,
                            num_workers=usable_workers(num_workers))  # fmt: skip
        for batch in loader:
            feats, mask = batch["features"].to(device), batch["mask"].to(device)
            if feats.dim() == 3:
                mu, _ = vae.encode(feats, mask)
                z, people = mu[:, None], torch.ones(feats.shape[0], 1, dtype=torch.bool)
            else:
                b, p = batch["people_mask"].shape
                rows = feats.flatten(0, 1)
                rows_mask = mask[:, None, :].expand(b, p, -1).flatten(0, 1)
                rows_mask = rows_mask & batch["people_mask"].to(device).flatten()[:, None]
                rows_mask[:, 0] = True  # empty slots: encode a dummy frame, masked below
                mu, _ = vae.encode(rows, rows_mask)
                z, people = mu.reshape(b, p, *mu.shape[1:]), batch["people_mask"]
            zs.append(z.cpu())
            masks.append(people)
            datasets.append(torch.as_tensor(batch["dataset"], dtype=torch.long).reshape(-1))
            captions.extend(batch["captions"])
            own.extend(batch.get("person_captions", [[] for _ in batch["captions"]]))
            bar.update(feats.shape[0])
    bar.close()
    vae.to(home)
    p_max = max(z.shape[1] for z in zs)
    z = torch.cat([_pad_people(z, p_max) for z in zs])
    people = torch.cat([_pad_people(m, p_max) for m in masks])
    return {"z": z, "people_mask": people, "dataset": torch.cat(datasets), "captions": captions,
            "person_captions": own}  # fmt: skip


def _pad_people(x: Tensor, p: int) -> Tensor:
    if x.shape[1] == p:
        return x
    pad = x.new_zeros(x.shape[0], p - x.shape[1], *x.shape[2:])
    return torch.cat([x, pad], dim=1)


class LatentBankDataset(Dataset):
    """Items of a latent bank: ``z`` (P, p, r), ``people_mask`` (P,), caption, dataset."""

    def __init__(self, bank: dict[str, Any], first_person_only: bool = False):
        self.bank = bank
        self.first = first_person_only

    def __len__(self) -> int:
        return int(self.bank["z"].shape[0])

    def set_epoch(self, epoch: int) -> None:  # the bank already holds many epochs
        pass

    def __getitem__(self, i: int) -> dict[str, Any]:
        z, people = self.bank["z"][i], self.bank["people_mask"][i]
        own = list(self.bank.get("person_captions", [[]] * len(self))[i])
        if self.first:
            z, people, own = z[:1], people[:1], own[:1]
        return {"z": z, "people_mask": people, "caption": self.bank["captions"][i],
                "person_captions": own, "dataset": int(self.bank["dataset"][i])}  # fmt: skip

    @staticmethod
    def collate(items: list[dict[str, Any]]) -> dict[str, Any]:
        return {
            "z": torch.stack([it["z"] for it in items]),
            "people_mask": torch.stack([it["people_mask"] for it in items]),
            "captions": [it["caption"] for it in items],
            "person_captions": [it["person_captions"] for it in items],
            "dataset": torch.tensor([it["dataset"] for it in items], dtype=torch.long),
        }


__all__ = ["MULTI_PERSON", "LatentBankDataset", "build_bank"]
