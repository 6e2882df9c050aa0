"""The salsa couple's picture: hands near and overlap against ``sflow.warm_take``, beside the
real takes.

    python research/salsa_figure.py SWEEP.json TEACH.json --out salsa.png

``SWEEP.json``: ``research/salsa_seeds.py --warm-take ... --json`` (every seed at every
value); ``TEACH.json``: ``research/teach_report.py --corpus ... --out`` (its real test and
val takes, whole: their first 4 s are the couple walking in, hands apart). Left: the share
of frames with hands near, per seed (dots) and the median (line), the real takes' as a
band; right: the bodies' mean overlap (cm), the same way. The chosen value is marked.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from umf.io import save_png_atomic

PANELS = (("hands_near", "hands near (share of frames)"),
          ("penetration_cm", "bodies overlap, mean depth (cm)"))  # fmt: skip


def medians(rows: list[dict], key: str) -> tuple[list[float], list[float]]:
    """The warm_take values in order and each one's median of ``key`` over its seeds."""
    takes = sorted({r["warm_take"] for r in rows})
    return takes, [float(np.median([r[key] for r in rows if r["warm_take"] == t])) for t in takes]


def draw(rows: list[dict], real: list[dict], out: Path, chosen: float | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, (key, title) in zip(axes, PANELS, strict=True):
        ax.scatter([r["warm_take"] for r in rows], [r[key] for r in rows], s=10, alpha=0.4,
                   color="tab:blue", label="a seed")  # fmt: skip
        takes, med = medians(rows, key)
        ax.plot(takes, med, color="tab:blue", marker="o", label="median of the seeds")
        values = [r[key] for r in real]
        if values:
            ax.axhspan(min(values), max(values), color="tab:green", alpha=0.2,
                       label="real test and val takes")  # fmt: skip
        if chosen is not None:
            ax.axvline(chosen, color="k", linestyle=":", label=f"chosen: {chosen:g}")
        ax.set_xlabel("sflow.warm_take")
        ax.set_title(title, fontsize=10)
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle('"Two people dance salsa together.", 4 s, delivered', fontsize=10)
    fig.tight_layout()
    save_png_atomic(fig, out, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("teach", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--chosen", type=float, default=None)
    args = ap.parse_args()
    rows = json.loads(args.sweep.read_text())
    real = json.loads(args.teach.read_text())["salsa"].get("real", [])
    draw(rows, real, args.out, args.chosen)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
