"""The InterHuman / HumanML3D evaluation protocol around a trained evaluator (SPEC 8).

Per replication (20 by default) the test items are shuffled with a seeded generator and
one of each item's captions is drawn. The complete groups of 96 of that order form the
evaluated set: R-precision top-1/2/3 and MM-Dist are computed group by group, FID against
the embeddings of *all* real test motions, Diversity over 300 pairs. Real data goes
through exactly the same steps (its FID is then not 0: a random subset against the whole
set, as in InterGen's script), giving the upper reference. Its rows also hold the
R-precision ceiling of the caption structure: items sharing a label (by default a pool
of captions) are indistinguishable to any text (:func:`umf.eval.metrics.retrieval_ceiling`).
A generator is scored on scenes it generates for the same captions and lengths;
MModality draws 30 samples for each of 100 prompts and compares 10 pairs. Each metric is
reported as mean and 95% half-width over replications (:func:`umf.eval.metrics.mean_ci`).

InterGen's script multiplies embeddings by 6 before FID and Diversity and halves the
Diversity difference (``fid_scale=6``, ``diversity_scale=3``); T2M's HumanML3D script uses
1 and 1. MM-Dist and MModality are never scaled. Deviation: InterGen's loaders group by
3 x 96 = 288 (``batch_size * 3``) despite its "fixed to 96" comment; SPEC 8 and this module
use ``group`` (96 by default).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from umf.data.corpus import Corpus
from umf.errors import UMFError
from umf.eval import metrics as M
from umf.eval.evaluator import MotionTextEvaluator
from umf.representation import FEATURE_DIM, canonicalize_features

Array = np.ndarray
Generate = Callable[[list[str], list[int], int], Sequence[Array]]
"""``generate(captions, frames, seed)``: one raw (P, frames_i, 262) scene per caption."""


@dataclass
class ProtocolConfig:
    """The numbers of the protocol (InterGen's defaults)."""

    replications: int = 20
    group: int = 96
    top_k: int = 3
    diversity_pairs: int = 300
    mm_prompts: int = 100  # 0 skips MModality
    mm_samples: int = 30
    mm_pairs: int = 10
    fid_scale: float = 6.0
    diversity_scale: float = 3.0
    max_frames: int = 300
    batch_size: int = 96
    seed: int = 0


@dataclass
class EvalItem:
    """One test item: raw features (P, T, 262) in person 1's canonical frame + captions.

    ``key``: what the captions were written from (e.g. a clip's action and style label);
    items with the same key are indistinguishable to any text, which bounds R-precision.
    ``None``: the item's caption pool.
    """

    features: Array
    captions: list[str]
    id: str = ""
    key: Hashable | None = None
    meta: dict = field(default_factory=dict)

    @property
    def text_key(self) -> Hashable:
        return self.key if self.key is not None else tuple(sorted(self.captions))

    @property
    def num_frames(self) -> int:
        return int(self.features.shape[1])


def corpus_items(corpus: Corpus, split: str = "test", kind: str = "interaction") -> list[EvalItem]:
    """The split's two-person scenes (``interaction``) or single-person clips (``single``)."""
    items: list[EvalItem] = []
    if kind == "interaction":
        for r in corpus.scenes.get(split, []):
            if r["num_people"] == 2:
                f = canonicalize_features(torch.from_numpy(corpus.scene_features(r))).numpy()
                items.append(EvalItem(f, list(r["captions"]), r["id"]))
        sources = [c for c in corpus.split_clips(split) if c.num_people == 2]
    elif kind == "single":
        sources = [c for c in corpus.split_clips(split) if c.num_people == 1]
    else:
        raise UMFError(f"unknown evaluator kind {kind!r}")
    for clip in sources:
        f = canonicalize_features(torch.from_numpy(corpus.clip_features(clip))).numpy()
        label = (clip.meta.get("content"), clip.meta.get("style"))
        key = label if any(label) else None  # paraphrases of one label say the same thing
        items.append(EvalItem(f, list(clip.captions), clip.id, key))
    items = [it for it in items if it.captions and it.num_frames >= 1]
    if not items:
        raise UMFError(f"{corpus.root}: no {kind} items with captions in split {split!r}")
    return items


# --------------------------------------------------------------------- embedding
@torch.no_grad()
def embed_motions(
    evaluator: MotionTextEvaluator,
    features: Sequence[Array | torch.Tensor],
    batch_size: int = 96,
    max_frames: int = 300,
) -> Array:
    """(N, E) motion embeddings of raw scenes (P, T_i, 262), padded per batch, eval mode.

    Scenes longer than ``max_frames`` keep their first ``max_frames`` frames.
    """
    evaluator.eval()
    device = evaluator.device
    out = []
    for i in range(0, len(features), batch_size):
        chunk = [
            torch.as_tensor(np.asarray(f), dtype=torch.float32)
            for f in features[i : i + batch_size]
        ]
        for f in chunk:
            if f.dim() != 3 or f.shape[-1] != FEATURE_DIM or f.shape[0] != evaluator.num_people:
                want = f"({evaluator.num_people}, T, {FEATURE_DIM})"
                raise UMFError(f"expected scenes {want}, got {tuple(f.shape)}")
        lengths = [min(f.shape[1], max_frames) for f in chunk]
        batch = torch.zeros(len(chunk), evaluator.num_people, max(lengths), FEATURE_DIM)
        mask = torch.zeros(len(chunk), max(lengths), dtype=torch.bool)
        for j, (f, n) in enumerate(zip(chunk, lengths, strict=True)):
            batch[j, :, :n] = f[:, :n]
            mask[j, :n] = True
        emb = evaluator.encode_motion(batch.to(device), mask.to(device))
        out.append(emb.float().cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, evaluator.cfg.embed_dim))


@torch.no_grad()
def embed_texts(
    evaluator: MotionTextEvaluator, texts: Sequence[str], batch_size: int = 96
) -> Array:
    """(N, E) text embeddings, eval mode."""
    evaluator.eval()
    out = [
        evaluator.encode_text(list(texts[i : i + batch_size])).float().cpu().numpy()
        for i in range(0, len(texts), batch_size)
    ]
    return np.concatenate(out) if out else np.zeros((0, evaluator.cfg.embed_dim))


def embed_scenes(
    evaluator: MotionTextEvaluator,
    features: Sequence[Array | torch.Tensor],
    texts: Sequence[str],
    batch_size: int = 96,
    max_frames: int = 300,
) -> tuple[Array, Array]:
    """(text embeddings, motion embeddings), both (N, E), of aligned captions and scenes."""
    if len(features) != len(texts):
        raise UMFError(f"{len(features)} scenes but {len(texts)} captions")
    return (
        embed_texts(evaluator, texts, batch_size),
        embed_motions(evaluator, features, batch_size, max_frames),
    )


# --------------------------------------------------------------------- one replication
def set_metrics(
    text_emb: Array,
    motion_emb: Array,
    reference_emb: Array,
    rng: np.random.Generator,
    cfg: ProtocolConfig,
) -> dict[str, float]:
    """Metrics of one evaluated set: aligned (N, E) pairs, N a multiple of ``cfg.group``.

    Diversity draws ``min(cfg.diversity_pairs, N)`` pairs (a test set smaller than 300 + 96
    cannot give 300 from its complete groups).
    """
    n = (len(text_emb) // cfg.group) * cfg.group
    t, m = text_emb[:n], motion_emb[:n]
    tops = M.r_precision(t, m, cfg.group, cfg.top_k)
    out = {f"r_precision_top{k + 1}": v for k, v in enumerate(tops)}
    out["mm_dist"] = M.mm_dist(t, m)
    out["fid"] = M.fid(cfg.fid_scale * reference_emb, cfg.fid_scale * m)
    pairs = min(cfg.diversity_pairs, n)
    out["diversity"] = M.diversity(cfg.diversity_scale * m, pairs, rng)
    return out


def aligned_scores(
    evaluator: MotionTextEvaluator,
    items: Sequence[EvalItem],
    scenes: Sequence[Array],
    replications: int = 5,
    cfg: ProtocolConfig | None = None,
) -> dict[str, float]:
    """Mean FID and R-precision top-3 of ``scenes`` (P, T_i, 262) aligned with ``items``
    (scene i shows item i: a reconstruction, or a generation around item i's real person),
    over ``replications`` draws of complete groups and captions (draw r seeded by [0, r],
    whatever ``cfg.replications`` and ``cfg.seed`` say; ``cfg`` gives the group size and
    the other protocol numbers); the real items are the FID reference. Passing the items'
    own features scores the real data."""
    cfg = cfg or ProtocolConfig()
    if len(scenes) != len(items):
        raise UMFError(f"{len(scenes)} scenes for {len(items)} items")
    real_emb = embed_motions(evaluator, [it.features for it in items], cfg.batch_size,
                             cfg.max_frames)  # fmt: skip
    emb = embed_motions(evaluator, scenes, cfg.batch_size, cfg.max_frames)
    caps = sorted({c for it in items for c in it.captions})
    text_of = dict(zip(caps, embed_texts(evaluator, caps, cfg.batch_size), strict=True))
    rows = []
    for r in range(replications):
        rng = np.random.default_rng([0, r])
        idx = rng.permutation(len(items))[: (len(items) // cfg.group) * cfg.group]
        text = np.stack([text_of[items[i].captions[int(rng.integers(len(items[i].captions)))]]
                         for i in idx])  # fmt: skip
        rows.append(set_metrics(text, emb[idx], real_emb, np.random.default_rng(r), cfg))
    return {k: float(np.mean([row[k] for row in rows])) for k in ("fid", "r_precision_top3")}


def _evaluated_set(items: Sequence[EvalItem], rng: np.random.Generator, group: int):
    """(shuffled item indices of the complete groups, one drawn caption per item)."""
    order = rng.permutation(len(items))
    captions = [items[i].captions[int(rng.integers(len(items[i].captions)))] for i in order]
    n = (len(items) // group) * group
    if n == 0:
        raise UMFError(f"the protocol needs at least {group} test items, got {len(items)}")
    return order[:n], captions[:n]


def score_protocol(
    evaluator: MotionTextEvaluator,
    real: Sequence[EvalItem],
    generate: Generate | None = None,
    cfg: ProtocolConfig | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict[str, tuple[float, float]]]:
    """``{"real": {metric: (mean, ci)}, "generated": {...}}`` over ``cfg.replications``.

    ``generate`` (optional) receives the replication's captions, the real items' frame
    counts and a seed (``cfg.seed + r``; ``+ 100_000`` for the MModality samples) and
    returns raw scenes in person 1's canonical frame (the pipeline's ``Scene.features``).
    """
    cfg = cfg or ProtocolConfig()
    say = log or (lambda s: None)
    real_motion = embed_motions(evaluator, [it.features for it in real], cfg.batch_size,
                                cfg.max_frames)  # fmt: skip
    unique = sorted({c for it in real for c in it.captions})
    text_of = dict(zip(unique, embed_texts(evaluator, unique, cfg.batch_size), strict=True))
    rows: dict[str, list[dict[str, float]]] = {"real": [], "generated": []}
    for r in range(cfg.replications):
        idx, captions = _evaluated_set(real, np.random.default_rng([cfg.seed, r]), cfg.group)
        text = np.stack([text_of[c] for c in captions])
        # the same Diversity draws for real and generated: identical scenes score identically
        div_key = [cfg.seed, r, 1]
        real_row = set_metrics(
            text, real_motion[idx], real_motion, np.random.default_rng(div_key), cfg
        )
        ceiling = M.retrieval_ceiling([real[i].text_key for i in idx], cfg.group, cfg.top_k)
        real_row |= {f"r_precision_ceiling_top{k + 1}": v for k, v in enumerate(ceiling)}
        rows["real"].append(real_row)
        if generate is not None:
            frames = [real[i].num_frames for i in idx]
            scenes = _checked(generate(list(captions), frames, cfg.seed + r), len(frames))
            gen = embed_motions(evaluator, scenes, cfg.batch_size, cfg.max_frames)
            row = set_metrics(text, gen, real_motion, np.random.default_rng(div_key), cfg)
            if cfg.mm_prompts > 0:
                mm_rng = np.random.default_rng([cfg.seed, r, 2])
                row["multimodality"] = _multimodality(evaluator, real, idx, captions, generate,
                                                      cfg, r, mm_rng)  # fmt: skip
            rows["generated"].append(row)
        say(f"replication {r + 1}/{cfg.replications}: " + _fmt(rows, r))
    return {name: _summarise(vals) for name, vals in rows.items() if vals}


def _multimodality(evaluator, real, idx, captions, generate, cfg, r, rng) -> float:
    """MModality of ``generate`` on the first ``mm_prompts`` items of the replication."""
    k = min(cfg.mm_prompts, len(idx))
    texts = [c for c in captions[:k] for _ in range(cfg.mm_samples)]
    frames = [real[i].num_frames for i in idx[:k] for _ in range(cfg.mm_samples)]
    scenes = _checked(generate(texts, frames, cfg.seed + 100_000 + r), len(frames))
    emb = embed_motions(evaluator, scenes, cfg.batch_size, cfg.max_frames)
    return M.multimodality(emb.reshape(k, cfg.mm_samples, -1), cfg.mm_pairs, rng)


def _checked(scenes: Sequence[Array], n: int) -> Sequence[Array]:
    if len(scenes) != n:
        raise UMFError(f"generate returned {len(scenes)} scenes for {n} captions")
    return scenes


def _summarise(rows: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    return {k: M.mean_ci([row[k] for row in rows]) for k in rows[0]}  # type: ignore[misc]


def _fmt(rows: dict[str, list[dict[str, float]]], r: int) -> str:
    parts = []
    for name, vals in rows.items():
        if len(vals) > r:
            v = vals[r]
            parts.append(f"{name} top3 {v['r_precision_top3']:.3f} FID {v['fid']:.3f}")
    return "; ".join(parts)


def format_results(results: dict[str, dict[str, tuple[float, float]]]) -> str:
    """A plain-text table: one row per metric, one ``mean ± ci`` column per source."""
    names = list(results)
    metrics = list(dict.fromkeys(k for res in results.values() for k in res))
    lines = ["metric".ljust(22) + "".join(n.rjust(22) for n in names)]
    for k in metrics:
        cells = []
        for n in names:
            v = results[n].get(k)
            cells.append(("-" if v is None else f"{v[0]:.4f} ± {v[1]:.4f}").rjust(22))
        lines.append(k.ljust(22) + "".join(cells))
    return "\n".join(lines)
