"""Error accumulation over the person index: does person k get worse as k grows?

UMF adds people one at a time (P-Flow for person 1, S-Flow reacting to everybody so far
for the rest), so errors may pile up with the person index. The study generates scenes
with N = 2..8 people and measures, for each person index k, quantities that need no
learned evaluator: penetration with the people generated before k, foot skating,
floating, ground penetration, jitter, and for reactions (k >= 2) how they face and keep
their distance to person 1. Running it for S-Flow and for the noise-free reaction-only
ablation gives one line per variant in :func:`plot_accumulation`.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from umf.data.relations import facing_dirs, root_xz
from umf.eval.physics import (
    as_numpy,
    penetration_matrix,
    penetration_with_previous,
    person_physics,
)
from umf.io import save_png_atomic, write_text_atomic

Generator = Callable[[list[str], int, int], Sequence[Any]]
"""``generate(prompts, num_people, seed)`` -> one scene (N, T, 22, 3) per prompt."""

# per-person metrics of the study, in plotting order, with axis labels
METRICS: dict[str, str] = {
    "penetration_prev_cm": "penetration with persons < k (cm)",
    "penetration_prev_frac": "frames penetrating persons < k",
    "skate_ratio": "foot skating ratio",
    "grounded_speed": "grounded foot speed (m/s)",
    "float_ratio": "floating ratio",
    "ground_pen_cm": "ground penetration (cm)",
    "jerk": "jerk (m/s^3)",
    "facing_p1_deg": "angle to face person 1 (deg)",
    "distance_p1_m": "distance to person 1 (m)",
}
REACTION_ONLY = ("penetration_prev_cm", "penetration_prev_frac", "facing_p1_deg", "distance_p1_m")


def relation_to_first(joints: Any) -> list[dict[str, float]]:
    """Per person k >= 2: mean over frames of the angle (deg) between k's facing direction
    and the direction from k to person 1, and of the floor distance (m) between roots.
    Person 1 gets an empty dict."""
    j = as_numpy(joints)
    out: list[dict[str, float]] = [{}]
    p1 = root_xz(j[0])  # (T, 2)
    for k in range(1, j.shape[0]):
        to_p1 = p1 - root_xz(j[k])
        dist = np.linalg.norm(to_p1, axis=-1)
        cos = (facing_dirs(j[k]) * to_p1).sum(-1) / np.maximum(dist, 1e-8)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        out.append({"facing_p1_deg": float(angle.mean()), "distance_p1_m": float(dist.mean())})
    return out


def person_index_metrics(joints: Any, fps: float = 30.0) -> list[dict[str, float]]:
    """The study's metrics (see :data:`METRICS`) for each person of one scene (N, T, 22, 3).

    Reaction-only metrics (penetration with earlier people, relation to person 1) are
    absent for person 1.
    """
    j = as_numpy(joints)
    prev = penetration_with_previous(j, matrix=penetration_matrix(j))
    rel = relation_to_first(j)
    out = []
    for k in range(j.shape[0]):
        m: dict[str, float] = {
            key: v for key, v in person_physics(j[k], fps).items() if key in METRICS
        }
        if k > 0:
            m["penetration_prev_cm"] = prev[k]["penetration_cm"]
            m["penetration_prev_frac"] = prev[k]["penetration_frac"]
            m.update(rel[k])
        out.append(m)
    return out


def accumulation_table(
    generate: Generator,
    prompts: Sequence[str],
    sizes: Iterable[int] = range(2, 9),
    seed: int = 0,
    fps: float = 30.0,
    variant: str = "S-Flow",
) -> list[dict[str, Any]]:
    """Tidy table of the study: one row per (N, k, metric).

    For every N in ``sizes`` the generator makes one scene per prompt (``seed`` is
    passed unchanged, so the variants compare on the same noise); each row holds the
    mean over those scenes of the metric of person k (1-based), NaNs ignored:
    ``{"variant", "N", "k", "metric", "value", "scenes"}``.
    """
    rows: list[dict[str, Any]] = []
    for n in sizes:
        scenes = generate(list(prompts), int(n), seed)
        per_scene = []
        for s in scenes:
            j = as_numpy(s)
            if j.shape[0] != n:
                raise ValueError(f"generator returned {j.shape[0]} people for N = {n}")
            per_scene.append(person_index_metrics(j, fps))
        for k in range(n):
            for metric in METRICS:
                vals = [p[k][metric] for p in per_scene if metric in p[k]]
                vals = [v for v in vals if math.isfinite(v)]
                if vals:
                    rows.append({
                        "variant": variant, "N": int(n), "k": k + 1, "metric": metric,
                        "value": float(np.mean(vals)), "scenes": len(vals),
                    })  # fmt: skip
    return rows


def save_table(table: Sequence[dict[str, Any]], path: str | Path) -> None:
    """The table as CSV, written atomically."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["variant", "N", "k", "metric", "value", "scenes"])
    writer.writeheader()
    writer.writerows(table)
    write_text_atomic(path, buf.getvalue())


def index_curve(
    table: Sequence[dict[str, Any]], variant: str, metric: str, n: int | None = None
) -> tuple[list[int], list[float]]:
    """(k, value) of one variant and metric: at one N, or pooled over all N (mean over
    the scenes that have a person k, weighted by their count)."""
    rows = [
        r
        for r in table
        if r["variant"] == variant and r["metric"] == metric and (n is None or r["N"] == n)
    ]
    ks = sorted({r["k"] for r in rows})
    values = []
    for k in ks:
        at = [r for r in rows if r["k"] == k]
        weight = sum(r["scenes"] for r in at)
        values.append(sum(r["value"] * r["scenes"] for r in at) / weight)
    return ks, values


def plot_accumulation(
    table: Sequence[dict[str, Any]], path: str | Path, metrics: Sequence[str] | None = None
) -> None:
    """One panel per metric, x = person index k, one bold line per variant (pooled over
    N) and a thin line per (variant, N); written atomically as PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    present = {r["metric"] for r in table}
    names = [m for m in (metrics or METRICS) if m in present]
    if not names:
        raise ValueError("nothing to plot: the table has none of the requested metrics")
    variants = list(dict.fromkeys(r["variant"] for r in table))
    sizes = sorted({r["N"] for r in table})
    cols = min(3, len(names))
    nrows = math.ceil(len(names) / cols)
    fig = Figure(figsize=(4.2 * cols, 3.2 * nrows), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, cols, squeeze=False).ravel()
    colours = [f"C{i}" for i in range(10)]
    for ax, name in zip(axes, names, strict=False):
        for i, variant in enumerate(variants):
            colour = colours[i % len(colours)]
            for n in sizes:
                ks, vals = index_curve(table, variant, name, n)
                if ks:
                    ax.plot(ks, vals, "-", color=colour, alpha=0.25, linewidth=0.8)
            ks, vals = index_curve(table, variant, name)
            if ks:
                ax.plot(ks, vals, "o-", color=colour, label=variant, markersize=3)
        ax.set_title(METRICS.get(name, name), fontsize=10)
        ax.set_xlabel("person index k")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    save_png_atomic(fig, path)
