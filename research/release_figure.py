"""Two releases side by side in one picture: how many seeds keep pace, and which groups pass.

    python research/release_figure.py OUT.png --keep NAME=KEEP.json [NAME=KEEP.json]
        --protocol NAME=metrics.json [NAME=metrics.json]

``KEEP.json``: ``research/keep_pace.py --json`` (any number of seeds); ``metrics.json``: the
``umf eval`` protocol's. Left: per scene (walk / run, 2 / 3 people), the share of seeds whose
followers all keep pace. Right: the test groups passing every relation check raw, by
relation.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def keep_shares(keep: dict) -> dict[str, float]:
    """Per scene of a ``keep_pace.py --json`` file, the share of seeds meeting the target."""
    return {scene: row["seeds_meeting_target"] / len(row["seeds"]) for scene, row in keep.items()}


def group_shares(metrics: dict) -> dict[str, float]:
    """The protocol's raw groups passing every check, by relation (the model's own entry:
    neither "real" nor the delivered one)."""
    groups = metrics["relations"]["groups"]
    (name,) = [k for k in groups if k != "real" and not k.endswith(", delivered")]
    return dict(groups[name]["by_relation"])


def draw(out: Path, keeps: dict[str, dict], protocols: dict[str, dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from umf.io import save_png_atomic

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for ax, data, title in ((axes[0], {k: keep_shares(v) for k, v in keeps.items()},
                             "followers keep pace (share of seeds)"),
                            (axes[1], {k: group_shares(v) for k, v in protocols.items()},
                             "test groups passing every check, raw")):  # fmt: skip
        labels = sorted({label for shares in data.values() for label in shares})
        width = 0.8 / max(len(data), 1)
        x = np.arange(len(labels))
        for i, (name, shares) in enumerate(data.items()):
            ax.bar(x + i * width, [shares.get(label, 0.0) for label in labels], width, label=name)
        ax.set_xticks(x + width * (len(data) - 1) / 2, labels, rotation=20)
        ax.set_ylim(0, 1)
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8, loc="lower right" if ax is axes[0] else "upper right")
    fig.tight_layout()
    save_png_atomic(fig, out, dpi=100)
    plt.close(fig)


def named_files(items: list[str]) -> dict[str, dict]:
    out = {}
    for item in items:
        name, _, path = item.partition("=")
        if not path:
            raise SystemExit(f"error: {item!r}: give NAME=FILE")
        out[name] = json.loads(Path(path).read_text())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--keep", nargs="+", default=[])
    ap.add_argument("--protocol", nargs="+", default=[])
    args = ap.parse_args()
    draw(args.out, named_files(args.keep), named_files(args.protocol))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
