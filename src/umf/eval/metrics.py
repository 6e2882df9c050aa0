"""The text-to-motion protocol metrics on embeddings (pure numpy / scipy).

Definitions follow the evaluation scripts of T2M (HumanML3D) and InterGen (InterHuman), which
the UMF paper reuses (SPEC 8):

- FID: Fréchet distance between Gaussians fitted to two sets of motion embeddings
  (sample mean, unbiased covariance ``np.cov``).
- R-precision: in each group of ``group`` aligned (text, motion) pairs, every text ranks the
  group's motions by Euclidean distance; top-k counts the texts whose own motion is among
  the k nearest. Incomplete trailing groups are dropped (the reference loaders use
  ``drop_last``).
- MM-Dist: mean Euclidean distance between matched text and motion embeddings.
- Diversity: mean distance between two independent draws of ``pairs`` embeddings (each draw
  without replacement).
- MModality: per prompt, mean distance between two independent draws of ``pairs`` of its
  samples (the same index draws for every prompt), averaged over prompts. As in the
  references, the two draws may pick the same sample (distance 0), which lowers the
  expectation by the factor ``1 - 1/S`` for S samples per prompt (``1 - 1/N`` for Diversity).
- Replications are summarised by their mean and the half-width ``1.96 * std / sqrt(n)``
  with the population std (``ddof=0``), as the reference scripts compute it.

Scaling conventions of a particular protocol (InterGen multiplies embeddings by 6 for FID
and Diversity) are applied by the caller (:mod:`umf.eval.protocol`), not here.
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Hashable, Sequence

import numpy as np
from scipy import linalg

Array = np.ndarray


def _as_2d(x: Array, name: str) -> Array:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"{name} must be (N, D), got shape {a.shape}")
    return a


def gaussian_stats(emb: Array) -> tuple[Array, Array]:
    """Mean (D,) and unbiased covariance (D, D) of embeddings (N, D), N >= 2."""
    e = _as_2d(emb, "emb")
    if e.shape[0] < 2:
        raise ValueError("need at least 2 embeddings for a covariance")
    return e.mean(axis=0), np.atleast_2d(np.cov(e, rowvar=False))


def frechet_distance(
    mu1: Array, sigma1: Array, mu2: Array, sigma2: Array, eps: float = 1e-6
) -> float:
    """||mu1 - mu2||^2 + Tr(S1 + S2 - 2 (S1 S2)^(1/2)) for N(mu1, S1) and N(mu2, S2).

    ``sqrtm`` of a nearly singular product can fail or return junk: then ``eps`` is added to
    both diagonals and it is retried. Round-off can leave small imaginary parts in the
    square root; they are dropped when negligible and reported otherwise.
    """
    mu1, mu2 = np.atleast_1d(mu1).astype(np.float64), np.atleast_1d(mu2).astype(np.float64)
    s1, s2 = np.atleast_2d(sigma1).astype(np.float64), np.atleast_2d(sigma2).astype(np.float64)
    if mu1.shape != mu2.shape or s1.shape != s2.shape or s1.shape != (mu1.size, mu1.size):
        raise ValueError("means and covariances have inconsistent shapes")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", linalg.LinAlgWarning)  # singular: handled below
        covmean = linalg.sqrtm(s1 @ s2)
        if not np.isfinite(covmean).all():
            offset = np.eye(s1.shape[0]) * eps
            covmean = linalg.sqrtm((s1 + offset) @ (s2 + offset))
    if np.iscomplexobj(covmean):
        scale = max(float(np.abs(np.diagonal(covmean)).max()), 1.0)
        if not np.allclose(np.diagonal(covmean).imag, 0.0, atol=1e-3 * scale):
            worst = float(np.abs(covmean.imag).max())
            raise ValueError(f"FID: sqrtm has a large imaginary component ({worst:.3g})")
        covmean = covmean.real
    diff = mu1 - mu2
    value = diff @ diff + np.trace(s1) + np.trace(s2) - 2.0 * np.trace(covmean)
    return float(value)


def fid(real_emb: Array, gen_emb: Array) -> float:
    """Fréchet distance between Gaussians fitted to real (N1, D) and generated (N2, D)."""
    return frechet_distance(*gaussian_stats(real_emb), *gaussian_stats(gen_emb))


def euclidean_distances(a: Array, b: Array) -> Array:
    """(N1, N2) matrix of ||a_i - b_j||, computed directly (no cancellation at 0)."""
    a, b = _as_2d(a, "a"), _as_2d(b, "b")
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


def _aligned(text_emb: Array, motion_emb: Array) -> tuple[Array, Array]:
    t, m = _as_2d(text_emb, "text_emb"), _as_2d(motion_emb, "motion_emb")
    if t.shape != m.shape:
        raise ValueError(f"text and motion embeddings differ in shape: {t.shape} vs {m.shape}")
    return t, m


def r_precision(
    text_emb: Array, motion_emb: Array, group: int = 96, top_k: int = 3
) -> tuple[float, ...]:
    """(top-1, ..., top-k) retrieval rates of aligned pairs in consecutive groups of ``group``.

    Row i of both arrays is one (text, motion) pair. Only complete groups count; at least
    one is needed. Random embeddings give about k / group; perfect ones give 1.
    """
    t, m = _aligned(text_emb, motion_emb)
    groups = t.shape[0] // group
    if group < top_k or groups == 0:
        raise ValueError(f"R-precision needs at least one group of {group} >= top_k pairs")
    hits = np.zeros(top_k)
    for g in range(groups):
        sl = slice(g * group, (g + 1) * group)
        dist = euclidean_distances(t[sl], m[sl])
        order = np.argsort(dist, axis=1, kind="stable")
        rank = np.argmax(order == np.arange(group)[:, None], axis=1)  # 0 = nearest
        hits += [(rank < k).sum() for k in range(1, top_k + 1)]
    return tuple(float(h) / (groups * group) for h in hits)


def retrieval_ceiling(
    keys: Sequence[Hashable], group: int = 96, top_k: int = 3
) -> tuple[float, ...]:
    """Expected R-precision of a perfect evaluator when texts cannot tell some items apart.

    Items with equal ``keys`` (e.g. the same pool of captions) look the same to any text, so
    at best the true motion lies at a random place among the m items of its group sharing
    its key: top-k is min(k, m) / m. An expectation, not a hard bound (a finite test set can
    land above it by chance). Same grouping as :func:`r_precision` (complete groups only).
    """
    keys = list(keys)
    groups = len(keys) // group
    if groups == 0:
        raise ValueError(f"need at least one group of {group} items")
    hits = np.zeros(top_k)
    for g in range(groups):
        counts = Counter(keys[g * group : (g + 1) * group])
        for m in (counts[k] for k in keys[g * group : (g + 1) * group]):
            hits += [min(k, m) / m for k in range(1, top_k + 1)]
    return tuple(float(h) / (groups * group) for h in hits)


def mm_dist(text_emb: Array, motion_emb: Array) -> float:
    """Mean Euclidean distance between matched text and motion embeddings."""
    t, m = _aligned(text_emb, motion_emb)
    return float(np.linalg.norm(t - m, axis=1).mean())


def diversity(emb: Array, pairs: int = 300, rng: np.random.Generator | None = None) -> float:
    """Mean distance between two independent draws of ``pairs`` embeddings (N >= pairs)."""
    e = _as_2d(emb, "emb")
    if e.shape[0] < pairs:
        raise ValueError(f"Diversity over {pairs} pairs needs >= {pairs} embeddings, got {len(e)}")
    rng = rng if rng is not None else np.random.default_rng()
    first = rng.choice(e.shape[0], pairs, replace=False)
    second = rng.choice(e.shape[0], pairs, replace=False)
    return float(np.linalg.norm(e[first] - e[second], axis=1).mean())


def multimodality(
    emb_per_prompt: Array, pairs: int = 10, rng: np.random.Generator | None = None
) -> float:
    """Mean distance between pairs of samples of the same prompt; input (P, S, D), S >= pairs."""
    e = np.asarray(emb_per_prompt, dtype=np.float64)
    if e.ndim != 3:
        raise ValueError(f"emb_per_prompt must be (prompts, samples, D), got shape {e.shape}")
    if e.shape[1] < pairs:
        raise ValueError(f"MModality over {pairs} pairs needs >= {pairs} samples per prompt")
    rng = rng if rng is not None else np.random.default_rng()
    first = rng.choice(e.shape[1], pairs, replace=False)
    second = rng.choice(e.shape[1], pairs, replace=False)
    return float(np.linalg.norm(e[:, first] - e[:, second], axis=-1).mean())


def mean_ci(values: Array) -> tuple[float, float] | tuple[Array, Array]:
    """(mean, 1.96 * std / sqrt(n)) over replications (axis 0), std with ddof=0.

    ddof=0 is what the T2M / InterGen scripts use (``np.std`` default); the interval is thus
    slightly narrower than a textbook t- or ddof=1 interval.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.shape[0] == 0:
        raise ValueError("mean_ci needs at least one value")
    mean = v.mean(axis=0)
    half = 1.96 * v.std(axis=0, ddof=0) / np.sqrt(v.shape[0])
    if v.ndim == 1:
        return float(mean), float(half)
    return mean, half
