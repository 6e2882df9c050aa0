"""How much runners side by side turn: the P-Flow's leader against the training crops.

    python research/runner_turns.py [MODEL_DIR] [--corpus CORPUS] [--seeds 8]

1. The train split's ``run_side_by_side`` scenes as the S-Flow and the reaction bank see
   them (4-second crops, person 1's frame, the model's ``repeat_scene_gait``): how far each
   person's path turns, the angle between its first and second 2-second chords
   (+: to the right; +x is the left of someone facing +z), and how fast person 2 drifts
   sideways from person 1 (:func:`sideways_drift`: two solo clips side by side do not keep
   their spacing).
2. "Two people run side by side." and "Three people run side by side." (4 s, seeds 0..N-1,
   delivered): the leader's turn, chord and path speed, and each follower's start and end
   along the leader's heading and speed over the leader's (``research/keep_pace.py``'s
   measure; FAIL: someone ends more than 1 m behind).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from keep_pace import pace
from runner_placement import run_crops

HALF = 60  # frames: the 2-second chords of a 4-second crop (30 fps)


def turn_deg(path: np.ndarray) -> float:
    """The angle (degrees, + to the right) from a floor path's (T, 2) first 2-second chord to
    its second."""
    a, b = path[HALF] - path[0], path[-1] - path[HALF]
    return float(np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))


def sideways_drift(joints: np.ndarray, fps: float) -> float:
    """How fast (m/s) person 2 of a scene (P, T, 22, 3) drifts sideways from person 1: the
    change of their pelvises' offset across person 1's start-to-end chord, over the crop."""
    p = joints[:2, :, 0][..., [0, 2]]
    chord = p[0, -1] - p[0, 0]
    across = np.array([chord[1], -chord[0]]) / max(float(np.linalg.norm(chord)), 1e-9)
    offset = (p[1] - p[0]) @ across
    return float(abs(offset[-1] - offset[0])) * fps / (p.shape[1] - 1)


def training_turns(pipe, corpus) -> None:
    turns: list[list[float]] = [[], []]
    drift = []
    for j in run_crops(pipe, corpus, 2 * HALF, mirror=True):
        for k in (0, 1):
            turns[k].append(turn_deg(j[k, :, 0][:, [0, 2]]))
        drift.append(sideways_drift(j, pipe.config.fps))
    for k, name in ((0, "person 1"), (1, "person 2")):
        t = np.array(turns[k])
        p10, p50, p90 = np.percentile(t, [10, 50, 90])
        wide = float(np.mean(abs(t) > 20))
        print(f"1. training crops ({len(t)}), {name}: turn p10 / median / p90 {p10:+.0f} / "
              f"{p50:+.0f} / {p90:+.0f} deg; more than 20 deg: {wide:.2f}")  # fmt: skip
    p50, p90 = np.percentile(drift, [50, 90])
    print(f"1. training crops ({len(drift)}): person 2 drifts sideways from person 1 at "
          f"{p50:.2f} m/s (median), {p90:.2f} (p90)")  # fmt: skip


def generated_turns(pipe, seeds: int) -> None:
    fps = pipe.config.fps
    for n, prompt in ((2, "Two people run side by side."), (3, "Three people run side by side.")):
        for s in range(seeds):
            (scene,) = pipe(prompt, num_people=n, seconds=4.0, seed=s)
            j = np.asarray(scene.joints)
            speed, end, start = pace(j, fps)
            p = j[0, :, 0][:, [0, 2]]
            path = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) * fps / (len(p) - 1)
            people, fail = [], False
            for k in range(1, n):
                ratio = speed[k] / max(speed[0], 1e-9)
                fail |= end[k] < -1.0 or abs(ratio - 1) > 0.2
                people.append(f"P{k + 1} start {start[k]:+.2f} end {end[k]:+.2f} m, "
                              f"{ratio:.2f}x")  # fmt: skip
            print(f"2. {n} people, seed {s}: leader turns {turn_deg(p):+.0f} deg, chord "
                  f"{speed[0]:.2f} m/s, path {path:.2f} m/s | "
                  + "; ".join(people) + (" FAIL" if fail else ""))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()

    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model)
    training_turns(pipe, Corpus.load(args.corpus))
    generated_turns(pipe, args.seeds)


if __name__ == "__main__":
    main()
