"""Training and validation loss of one or more runs, from their ``metrics.csv``, as a PNG.

Each run's stage directory (``RUN/pflow``, ``RUN/sflow``, ``RUN/vae``) holds a
``metrics.csv`` of ``step,split,name,value,seconds`` rows; this plots the ``total`` of the
train and val splits against the step, one colour per run.

    python research/loss_curve.py OUT.png LABEL=RUN/pflow/metrics.csv [LABEL=... ...]
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path


def read_totals(path: Path) -> dict[str, list[tuple[int, float]]]:
    """{split: [(step, total)]} of one metrics.csv."""
    out: dict[str, list[tuple[int, float]]] = {}
    with open(path, newline="") as f:
        for row in csv.reader(f):
            if len(row) >= 4 and row[2] == "total" and row[0].isdigit():
                out.setdefault(row[1], []).append((int(row[0]), float(row[3])))
    return out


def main() -> None:
    if len(sys.argv) < 3 or any("=" not in a for a in sys.argv[2:]):
        sys.exit(__doc__.strip().splitlines()[-1].strip())
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for i, arg in enumerate(sys.argv[2:]):
        label, path = arg.split("=", 1)
        for split, style in (("train", "-"), ("val", "o--")):
            points = read_totals(Path(path)).get(split, [])
            if points:
                steps, values = zip(*points, strict=True)
                ax.plot(steps, values, style, color=f"C{i}", label=f"{label} {split}")
    ax.set_xlabel("step")
    ax.set_ylabel("flow-matching loss (total)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(sys.argv[1], dpi=110)
    print(sys.argv[1])


if __name__ == "__main__":
    main()
