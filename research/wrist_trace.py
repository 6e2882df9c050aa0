"""Does a generated wave wave? The right wrist's side-to-side swing over time, as a picture.

A wave is a side-to-side swing of the raised hand (about once a second); five still frames
cannot show it, and a hand held up still looks like a wave in them. This plots, for real
clips of a label and for people generated from its prompt by each model (4 s, seed 0 or
``--seed``, raw decoded motion: the draws of ``research/motion_stats_report.py``), the right wrist's
sideways offset from the pelvis in the person's own frame (heading at frame 0) over time,
one panel per source, and prints each source's medians of the root-relative right-wrist
speed and of the swings per second (turns after at least 10 cm; ``umf.eval.motion_stats``,
the statistics the label check uses), and how many people swing at least once a second.

    python research/wrist_trace.py NAME=MODEL_DIR [NAME=MODEL_DIR ...] --out FILE.png
        [--corpus out/corpus] [--label wave-right-hand] [--people 6] [--seed 0]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from umf.eval import motion_stats as MS


def plot(traces: dict[str, Sequence[np.ndarray]], stats: dict[str, list[float]], path: Path,
         label: str, fps: float = 30.0) -> None:  # fmt: skip
    """One panel per source, its people's traces over time; written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from umf.io import save_png_atomic

    fig, axes = plt.subplots(len(traces), 1, figsize=(8, 1.9 * len(traces)), sharex=True,
                             sharey=True, squeeze=False)  # fmt: skip
    for ax, (name, people) in zip(axes[:, 0], traces.items(), strict=True):
        for y in people:
            ax.plot(np.arange(len(y)) / fps, (y - y.mean()) * 100, lw=1)
        speed, swings = stats[name]
        ax.set_title(f"{name}: medians {speed:.2f} m/s right-wrist speed, {swings:.2f} "
                     "swings/s", fontsize=9)  # fmt: skip
        ax.set_ylabel("cm", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("seconds")
    fig.suptitle(f"{label}: right wrist, sideways from the pelvis (each line one person)",
                 fontsize=10)  # fmt: skip
    fig.tight_layout()
    save_png_atomic(fig, path, dpi=90)
    plt.close(fig)


def main() -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="NAME=MODEL_DIR")
    ap.add_argument("--out", required=True, help="PNG file")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--label", default="wave-right-hand", choices=sorted(MS.LABELS))
    ap.add_argument("--people", type=int, default=6, help="people per panel")
    ap.add_argument("--seed", type=int, default=0, help="sampling seed of the 16 people")
    args = ap.parse_args()
    torch.set_num_threads(2)
    real = MS.real_joints_by_label(Corpus.load(args.corpus), labels=[args.label])[args.label]
    real = [j[:121] for j in real if len(j) >= 121]  # 4 s, as generated
    sources = {"real clips": real}
    for spec in args.models:
        name, path = spec.rsplit("=", 1)  # the name may hold "=", a path seldom does
        pipe = UMFPipeline.from_pretrained(path)
        scenes = pipe([MS.LABELS[args.label][0]] * 16, num_people=1, seconds=4.0,
                      seed=args.seed, fit=False)  # fmt: skip
        sources[name] = [s.joints[0] for s in scenes]
    names = ["right_wrist_energy", "right_wrist_swings"]
    rows = {k: [MS.motion_statistics(j) for j in v] for k, v in sources.items()}  # once each
    stats = {k: MS.medians(v, names) for k, v in rows.items()}
    for k, (speed, swings) in stats.items():
        every = [r["right_wrist_swings"] for r in rows[k]]
        print(
            f"{k}: medians over {len(sources[k])} people: right-wrist speed {speed:.2f} m/s, "
            f"{swings:.2f} swings/s of at least {MS.SWING:.2f} m; "
            f"{sum(s >= 1.0 for s in every)} of {len(every)} swing at least once a second"
        )
    traces = {k: [MS.sideways(j) for j in v[: args.people]] for k, v in sources.items()}
    plot(traces, stats, Path(args.out), args.label)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
