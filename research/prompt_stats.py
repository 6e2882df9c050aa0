"""Motion statistics of generated single people for prompts of your choice.

How much does the wording of a prompt matter? Each prompt gives ``--samples`` people (4 s,
seed 0, raw decoded motion: the same draws as ``research/motion_stats_report.py``), and one
row of medians of ``umf.eval.motion_stats.motion_statistics`` (speeds m/s, heights m).
With ``--label`` a first row gives the corpus's real single-person clips of that content
label (any label of the corpus, e.g. walk-back; all splits pooled, at most 300 frames each).

    python research/prompt_stats.py MODEL_DIR "A person walks backward." \\
        "Somebody walks backwards." --label walk-back [--corpus out/corpus]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np
import torch

from umf.eval import motion_stats as MS

STATS = ("pelvis_speed", "backward_speed", "ankle_energy", "wrist_energy", "head_drop")


def median_row(people: Sequence[np.ndarray], stats: Sequence[str] = STATS) -> list[float]:
    """Median of each statistic over people (each (T, 22, 3) joints)."""
    return MS.median_statistics(people, stats)


def real_people(corpus, label: str) -> list[np.ndarray]:
    """Joints of every single-person clip of a content label, train, val and test pooled."""
    return MS.real_joints_by_label(corpus, labels=(label,)).get(label, [])


def format_rows(rows: Sequence[tuple[str, int, list[float]]], stats=STATS) -> str:
    head = "| prompt | people | " + " | ".join(stats) + " |"
    rule = "|---|---:|" + "---:|" * len(stats)
    body = [f"| {name} | {n} | " + " | ".join(f"{v:.2f}" for v in vals) + " |"
            for name, n, vals in rows]  # fmt: skip
    return "\n".join([head, rule, *body])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("prompts", nargs="+")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--label", help="a content label of the corpus (e.g. walk-back): a row of "
                    "its real single-person clips, all splits pooled")  # fmt: skip
    ap.add_argument("--corpus", default="out/corpus")
    args = ap.parse_args()
    if args.samples < 1:
        ap.error(f"--samples must be at least 1, got {args.samples}")
    torch.set_num_threads(2)
    from umf.pipeline import UMFPipeline

    rows = []
    if args.label:
        from umf.data.corpus import Corpus

        real = real_people(Corpus.load(args.corpus), args.label)
        if not real:
            raise SystemExit(f"no real clips of label {args.label!r} in {args.corpus}")
        rows.append((f"real clips: {args.label}", len(real), median_row(real)))
    pipe = UMFPipeline.from_pretrained(args.model)
    for prompt in args.prompts:
        scenes = pipe([prompt] * args.samples, num_people=1, seconds=4.0, seed=0, fit=False)
        rows.append((prompt, args.samples, median_row([s.raw_joints[0] for s in scenes])))
    print(format_rows(rows))


if __name__ == "__main__":
    main()
