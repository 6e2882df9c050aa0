"""What a training run records: `metrics.csv` (a row per logged value, kept across
resumes), TensorBoard when installed, and `loss_curves.png`."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from umf.io import atomic_path, save_png_atomic

Log = Callable[[str], None]
METRICS_FILE, CURVES_FILE = "metrics.csv", "loss_curves.png"
NOT_PLOTTED = frozenset({"lr", "grad_norm"})


# --------------------------------------------------------------------- metrics
class Row(NamedTuple):
    step: int
    split: str
    name: str
    value: float
    time: float


class MetricsLog:
    """``metrics.csv`` (step, split, name, value, time) + optional TensorBoard + history."""

    HEADER = ("step", "split", "name", "value", "time")

    def __init__(self, out_dir: Path, *, resume_step: int | None, tensorboard: bool, log: Log):
        self.path = out_dir / METRICS_FILE
        self.rows: list[Row] = []
        if resume_step is not None and self.path.exists():
            # drop what a killed run logged after its last checkpoint
            self.rows = [r for r in read_metrics(self.path) if r.step <= resume_step]
        self._rewrite()
        self.tb = _tensorboard(out_dir, resume_step or 0, log) if tensorboard else None

    def _rewrite(self) -> None:
        with atomic_path(self.path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(self.HEADER)
            w.writerows(self.rows)

    def add(self, step: int, split: str, values: Mapping[str, float], seconds: float) -> None:
        new = [Row(step, split, k, float(v), round(seconds, 3)) for k, v in values.items()]
        self.rows.extend(new)
        with open(self.path, "a", newline="") as fh:
            csv.writer(fh).writerows(new)
        if self.tb is not None:
            for r in new:
                self.tb.add_scalar(f"{split}/{r.name}", r.value, step)
            self.tb.flush()

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


def read_metrics(path: Path) -> list[Row]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return [
            Row(int(r["step"]), r["split"], r["name"], float(r["value"]), float(r["time"]))
            for r in reader
        ]


def _tensorboard(out_dir: Path, purge_step: int, log: Log) -> Any:
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        log("tensorboard is not installed: metrics go to metrics.csv only")
        return None
    return SummaryWriter(str(out_dir / "tensorboard"), purge_step=purge_step)


def plot_curves(rows: Sequence[Row], path: Path) -> None:
    """One panel per loss term, train line + val points, written atomically as PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = sorted({r.name for r in rows if r.name not in NOT_PLOTTED})
    if not names:
        return
    cols = min(3, len(names))
    nrows = math.ceil(len(names) / cols)
    fig = Figure(figsize=(4.2 * cols, 3.2 * nrows), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, cols, squeeze=False).ravel()
    for ax, name in zip(axes, names, strict=False):
        values = []
        for split, style in (("train", "-"), ("val", "o-")):
            pts = [(r.step, r.value) for r in rows
                   if r.name == name and r.split == split and math.isfinite(r.value)]  # fmt: skip
            if pts:
                ax.plot(*zip(*pts, strict=True), style, label=split, markersize=3)
                values += [v for _, v in pts]
        if values and min(values) > 0:
            ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    save_png_atomic(fig, path)
