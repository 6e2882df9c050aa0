"""Motion statistics of generated single people per label, for one or more models.

16 people per label from the label's prompt, 4 s, seed 0, raw decoded motion (no fit),
against the corpus's real clips of that label (``umf.eval.motion_stats``); the same check
as ``umf eval``'s section 5 without the rest of the evaluation. ``--delivered`` scores the
people as the default pipeline hands them out instead (feet anchored, bodies fitted: the
"delivered" rows of ``umf eval``).

    python scripts/motion_stats_report.py MODEL_DIR [MODEL_DIR ...] [--delivered]
        [--corpus out/corpus]
"""

from __future__ import annotations

import argparse

import torch

from umf.data.corpus import Corpus
from umf.eval import motion_stats as MS
from umf.pipeline import UMFPipeline


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--delivered", action="store_true", help="score the pipeline's output")
    args = ap.parse_args()
    torch.set_num_threads(2)
    real = MS.real_joints_by_label(Corpus.load(args.corpus))
    for path in args.models:
        pipe = UMFPipeline.from_pretrained(path)

        def generate(prompt: str, n: int, pipe: UMFPipeline = pipe) -> list:
            scenes = pipe([prompt] * n, num_people=1, seconds=4.0, seed=0, fit=args.delivered)
            return [s.joints[0] for s in scenes]  # fit=False: joints are the raw positions

        rows = MS.check_labels(real, generate, samples=args.samples)
        kind, passes = ("delivered" if args.delivered else "raw"), MS.label_passes(rows)
        print(f"## {path} ({kind}): {sum(passes.values())}/{len(passes)}")
        print(MS.format_checks(rows), flush=True)


if __name__ == "__main__":
    main()
