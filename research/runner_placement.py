"""Where runners side by side stand: the training crops against the S-Flow's first pass.

1. The train split's ``run_side_by_side`` scenes as the S-Flow sees them (``SceneDataset``
   with the model's ``repeat_scene_gait``, crops of 2 and 4 s, person 1's frame): person 2's
   distance to the side at the crop's first frame, and the leader's speed.
2. "Two people run side by side, the second person on the first one's left / right." (4 s,
   seeds 0..N-1): the S-Flow's first pass for person 2 (before any warm start), sideways
   position at the first and the last frame as decoded (positions as the pipeline fuses them
   for people 2..N), and where the delivered scene puts them at the start.

    python research/runner_placement.py [MODEL_DIR] [--corpus CORPUS] [--seeds 6]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

import umf.warm_start as warm_start
from umf.data.corpus import Corpus
from umf.pipeline import UMFPipeline, default_model_dir
from umf.representation import features_to_joints
from umf.train.datasets import SceneDataset


def run_crops(pipe: UMFPipeline, corpus: Corpus, frames: int, mirror: bool = False):
    """Joints (N, T, 22, 3) of each train ``run_side_by_side`` scene as the S-Flow's loader
    crops it to ``frames`` (person 1's frame, the model's ``repeat_scene_gait``; ``mirror``:
    mirrored at random, as the S-Flow and the reaction bank see them); scenes too short for
    the crop are left out."""
    ds = SceneDataset(corpus, "train", pipe.normalizer, min_frames=frames, max_frames=frames,
                      mirror=mirror, seed=0,
                      repeat_gait=pipe.config.train_sflow.repeat_scene_gait)  # fmt: skip
    for i, (kind, item, _) in enumerate(ds.items):
        if kind == "scene" and item.get("relation") == "run_side_by_side":
            f = ds[i]["features"]
            if f.shape[1] == frames:
                yield features_to_joints(pipe.normalizer.denormalize(f)).numpy()


def training_crops(pipe: UMFPipeline, corpus: Corpus) -> None:
    for frames in (60, 120):
        side, speed = [], []
        for j in run_crops(pipe, corpus, frames):
            side.append(abs(j[1, 0, 0, 0]))
            speed.append(np.linalg.norm(j[0, -1, 0, [0, 2]] - j[0, 0, 0, [0, 2]]) * pipe.config.fps
                         / (frames - 1))  # fmt: skip
        p10, p50, p90 = np.percentile(side, [10, 50, 90])
        print(
            f"1. training crops of {frames} frames ({len(side)}): person 2 {p50:.2f} m to the "
            f"side (p10-p90 {p10:.2f}-{p90:.2f}); leader {np.median(speed):.2f} m/s"
        )


def first_passes(pipe: UMFPipeline, seeds: int) -> None:
    seen = []
    real = warm_start.proposal

    def spy(p, first, decoded, *args, **kwargs):  # the first pass, as the warm start reads it
        seen.append(features_to_joints(decoded).numpy())
        return real(p, first, decoded, *args, **kwargs)

    warm_start.proposal = spy
    try:
        for side in ("left", "right"):
            prompt = f"Two people run side by side, the second person on the first one's {side}."
            for seed in range(seeds):
                seen.clear()
                (s,) = pipe(prompt, num_people=2, seconds=4.0, seed=seed, fit=False,
                            separate=False)  # fmt: skip
                x0, x1 = seen[0][0, 0, 0, 0], seen[0][0, -1, 0, 0]
                final = s.joints[1, 0, 0, 0] - s.joints[0, 0, 0, 0]
                print(
                    f"2. {side:5s} seed {seed}: first pass {x0:+.2f} m -> {x1:+.2f} m at the "
                    f"end; scene start {final:+.2f} m (+: person 1's left)"
                )
    finally:
        warm_start.proposal = real


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model or default_model_dir())
    training_crops(pipe, Corpus.load(args.corpus))
    first_passes(pipe, args.seeds)


if __name__ == "__main__":
    main()
