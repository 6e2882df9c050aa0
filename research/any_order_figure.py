"""The groups' picture: scenes passing every check, as recorded and in any order of the
people their caption leaves open, raw and delivered, per relation.

    python research/any_order_figure.py METRICS.json --out groups.png [--model NAME]

``METRICS.json``: ``umf eval``'s ``metrics.json`` (its ``relations.groups``). The recorded
order is the target reading; "any order" (:func:`umf.eval.relations.any_order_checks`) asks
only what the caption asks: a row that walks in a row passes whoever stands where.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from umf.io import save_png_atomic


def bars(groups: dict, model: str) -> tuple[list[str], dict[str, list[float]]]:
    """The relations of the groups and, per reading ("raw", "raw, any order", "delivered",
    "delivered, any order"), the share of each relation's scenes passing every check."""
    raw, delivered = groups[model], groups[f"{model}, delivered"]
    relations = sorted(raw["by_relation"])
    out = {}
    for name, acc in (("raw", raw), ("delivered", delivered)):
        out[name] = [acc["by_relation"][r] for r in relations]
        out[f"{name}, any order"] = [acc["any_order"]["by_relation"][r] for r in relations]
    return relations, out


def draw(groups: dict, model: str, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    relations, values = bars(groups, model)
    fig, ax = plt.subplots(figsize=(8, 3.6))
    width = 0.8 / len(values)
    colours = ("tab:blue", "tab:blue", "tab:orange", "tab:orange")
    for i, ((name, v), colour) in enumerate(zip(values.items(), colours, strict=True)):
        ax.bar(np.arange(len(relations)) + i * width, v, width, label=name, color=colour,
               alpha=0.45 if "any order" in name else 0.9,
               hatch="//" if "any order" in name else None)  # fmt: skip
    ax.set_xticks(np.arange(len(relations)) + 0.4 - width / 2, relations)
    ax.set_ylim(0, 1.15)
    ax.set_ylabel("scenes passing every check")
    ax.set_title(f"{model}: zero-shot test groups of 3-6, as recorded and in any order",
                 fontsize=10)  # fmt: skip
    ax.legend(fontsize=7, ncol=4, loc="upper center")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    save_png_atomic(fig, out, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("metrics", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--model", default=None, help="default: the report's first model")
    args = ap.parse_args()
    m = json.loads(args.metrics.read_text())
    model = args.model or next(s["name"] for s in m["sources"] if s["role"] == "model")
    draw(m["relations"]["groups"], model, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
