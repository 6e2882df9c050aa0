"""Where S-Flow puts person 2 around a *real* person 1: a placement diagnosis.

For the first K two-person scenes of a split, the real person 1 is given as the actor (the
pipeline's react mode) and person 2 is generated from the scene's first caption, raw (no
separation, no fit). Per model: the median over scenes of the mean floor distance between
the two pelvises, generated against the real person 2's, the share of scenes whose
generated distance is within 50 cm of the real one, the median error of the distance in
the first frame alone (where person 2 starts), and person 2's pelvis speed. With
person 1 fixed to real motion, a wrong distance is the S-Flow's alone, not the P-Flow's.

    python research/react_placement.py MODEL_DIR [MODEL_DIR ...] [--split val] [--scenes 64]
        [--sflow-steps S]
"""

from __future__ import annotations

import argparse

import numpy as np

from umf.data.clip import FPS
from umf.data.corpus import Corpus
from umf.eval.motion_stats import PELVIS, motion_statistics
from umf.pipeline import UMFPipeline

FRAMES = 150  # 5 s at 30 fps: inside every model's max_frames and the flows' training crops


def pelvis_gaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per frame, the floor distance (m) between two people's pelvises, (T, 22, 3) each."""
    return np.linalg.norm(a[:, PELVIS, [0, 2]] - b[:, PELVIS, [0, 2]], axis=-1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="+")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--split", default="val")
    ap.add_argument("--scenes", type=int, default=64)
    ap.add_argument("--sflow-steps", type=int, default=None, help="default: the model's")
    args = ap.parse_args()
    corpus = Corpus.load(args.corpus)
    recipes = [r for r in corpus.scenes[args.split] if r["num_people"] == 2][: args.scenes]
    real = [corpus.scene_joints(r)[:, :FRAMES] for r in recipes]
    gaps_real = [pelvis_gaps(j[0], j[1]) for j in real]
    d_real = np.array([g.mean() for g in gaps_real])
    s_real = np.array([g[0] for g in gaps_real])
    v_real = np.array([motion_statistics(j[1], FPS)["pelvis_speed"] for j in real])
    print(
        f"{len(recipes)} {args.split} pair scenes, {FRAMES} frames; real person 2: distance "
        f"median {np.median(d_real):.2f} m, pelvis speed median {np.median(v_real):.2f} m/s"
    )
    print("model | distance median (m) | median |gen - real| (m) | within 0.5 m | "
          "median |gen - real| at frame 0 (m) | p2 speed (m/s)")  # fmt: skip
    for path in args.models:
        pipe = UMFPipeline.from_pretrained(path)
        d_gen, s_gen, v_gen = [], [], []
        for r, j in zip(recipes, real, strict=True):
            scene = pipe(r["captions"][0], num_people=2, seed=0, actor=j[0].astype(np.float32),
                         separate=False, fit=False, sflow_steps=args.sflow_steps)[0]  # fmt: skip
            g = scene.joints
            gaps = pelvis_gaps(g[0], g[1])
            d_gen.append(gaps.mean())
            s_gen.append(gaps[0])
            v_gen.append(motion_statistics(g[1], pipe.config.fps)["pelvis_speed"])
        d_gen, v_gen = np.array(d_gen), np.array(v_gen)
        err, err0 = np.abs(d_gen - d_real), np.abs(np.array(s_gen) - s_real)
        print(f"{pipe.name} | {np.median(d_gen):.2f} | {np.median(err):.2f} | "
              f"{(err <= 0.5).mean():.0%} | {np.median(err0):.2f} | {np.median(v_gen):.2f}",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
