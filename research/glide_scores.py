"""Which people 2..N glide? ``umf.warm_start.glide_score`` (the slower ankle's mean floor
speed over the pelvis's; 0 for a person travelling under 0.5 m/s) on a model's sampled
people 2..N, by prompt, beside the real people 2..N of a corpus's test scenes, by relation:
what ``sflow.warm_glide`` is calibrated on.

    python research/glide_scores.py [--model DIR] [--corpus DIR] [--seeds 4] [--json FILE]

The model's people are scored as decoded (``scene.raw_joints``: the first pass the warm
start judges, before any clean-up). A stride keeps one ankle near rest; a glide carries
both along with the pelvis.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

PROMPTS = (
    ("Two people walk side by side.", 2),
    ("Three people walk side by side.", 3),
    ("Two people run side by side.", 2),
    ("A person calls out and another person walks over to them.", 2),
    ("One person punches while the other person retreats.", 2),
    ("Two people walk past each other.", 2),
    ("Two people bow to each other.", 2),
    ("Two people stand facing each other.", 2),
    ("Two people dance salsa together.", 2),
)


def scores(joints: np.ndarray, fps: float) -> list[float]:
    """glide_score of people 2..N of joints (P, T, 22, 3)."""
    import torch

    from umf.representation import joints_to_features
    from umf.warm_start import glide_score

    feats = torch.stack([joints_to_features(torch.as_tensor(np.asarray(j), dtype=torch.float32))
                         for j in joints[1:]])  # fmt: skip
    return [round(float(s), 3) for s in glide_score(feats, fps)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    fps = pipe.config.fps
    out: dict = {"model": pipe.name, "generated": {}, "real": {}}
    print(f"{pipe.name}: glide scores of people 2..N, decoded, seeds 0-{args.seeds - 1}")
    for prompt, n in PROMPTS:
        s = [x for seed in range(args.seeds)
             for x in scores(pipe(prompt, num_people=n, seconds=4.0, seed=seed)[0].raw_joints,
                             fps)]  # fmt: skip
        out["generated"][prompt] = s
        print(f"  {prompt:58s} min {min(s):.2f}  median {np.median(s):.2f}  max {max(s):.2f}")
    if args.corpus is not None:
        from umf.data.corpus import Corpus

        corpus = Corpus.load(args.corpus)
        by: dict[str, list[float]] = {}
        for rec in corpus.scenes["test"]:
            by.setdefault(rec["relation"], []).extend(scores(corpus.scene_joints(rec), fps))
        print(f"real people 2..N of {args.corpus}'s test scenes, by relation")
        for rel, s in sorted(by.items()):
            out["real"][rel] = s
            print(f"  {rel:24s} n {len(s):3d}  median {np.median(s):.2f}  "
                  f"p90 {np.percentile(s, 90):.2f}  max {max(s):.2f}")  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
