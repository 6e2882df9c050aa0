"""Per-person text matching: does each person do what their own prompt says?

For a model with per-person prompts (``denoiser.person_text``): the composed test scenes
whose people play different actions are generated from the scene's first caption with each
person's own prompt (the first wording of the clip they play), and each generated person,
re-centred on their first frame, is scored by the single-person evaluator against their own
prompt and every other person's prompt of the scene. Top-1: their own is nearest. With two
people chance is 0.5. Raw output (``fit=False, separate=False``), as the protocol scores.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from umf.data.corpus import Corpus
from umf.text import mirror_caption

Log = Callable[[str], None]


def person_items(corpus: Corpus, split: str = "test") -> list[tuple[str, list[str]]]:
    """(scene caption, each person's own prompt) of the split's composed scenes whose
    people all play different actions (a mirrored person's prompt has its sides swapped)."""
    captions = {c.id: c.captions for c in corpus.clips}
    items = []
    for r in corpus.scenes.get(split, []):
        people = r["people"]
        contents = [p.get("content") for p in people]
        if len(set(contents)) < len(contents) or not all(captions.get(p["clip"]) for p in people):
            continue
        first = [captions[p["clip"]][0] for p in people]
        own = [mirror_caption(o) if p.get("mirrored") else o
               for o, p in zip(first, people, strict=True)]  # fmt: skip
        items.append((r["captions"][0], own))
    return items


def top1(motion: np.ndarray, texts: np.ndarray) -> list[bool]:
    """Per person of one scene: is their motion embedding (P, E) nearest their own prompt's
    (row k of texts (P, E)) among the scene's P prompts?"""
    dist = np.linalg.norm(motion[:, None] - texts[None], axis=-1)  # (P motions, P texts)
    return [bool(np.argmin(row) == k) for k, row in enumerate(dist)]


@torch.no_grad()
def person_matching(
    pipe: Any,
    evaluator: Any,
    items: Sequence[tuple[str, list[str]]],
    seed: int = 0,
    seconds: float = 4.0,
    log: Log | None = None,
) -> dict[str, Any]:
    """Top-1 of own prompt against the others', over every person of ``items``."""
    from umf.eval.protocol import embed_motions, embed_texts
    from umf.representation import canonicalize_features

    hits: list[bool] = []
    for i, (caption, own) in enumerate(items):
        scene = pipe(caption, num_people=len(own), seconds=seconds, seed=seed,
                     person_prompts=own, fit=False, separate=False)[0]  # fmt: skip
        people = [canonicalize_features(torch.from_numpy(scene.features[k : k + 1]).float())
                  for k in range(len(own))]  # fmt: skip
        hits += top1(embed_motions(evaluator, people), embed_texts(evaluator, own))
        if log is not None and (i + 1) % 50 == 0:
            log(f"per-person matching: {i + 1}/{len(items)} scenes")
    n = len(hits)
    rate = float(np.mean(hits)) if n else float("nan")
    half = 1.96 * float(np.sqrt(rate * (1 - rate) / n)) if n else float("nan")
    chance = float(np.mean([1 / len(own) for _, own in items for _ in own])) if n else 0.0
    return {"scenes": len(items), "people": n, "top1": rate, "ci95": half, "chance": chance}
