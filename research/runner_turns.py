"""How much runners side by side turn: the P-Flow's leader against the training crops.

    python research/runner_turns.py [MODEL_DIR] [--corpus CORPUS] [--seeds 8] [--causes]

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
3. With ``--causes``: how long the training runners last and how many of them the flows'
   crops carry to 4 s, whether the VAE bends them, the P-Flow's leader alone ("A person
   runs.", and the pair's prompt at other step budgets and guidance scales), and the
   leader's turn against the scene's length (2.6-5 s: runners of the pair's prompt curve
   more the longer they run past their training scenes; walkers and a runner alone do not).
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


def turn_halves(path: np.ndarray) -> float:
    """:func:`turn_deg` between the chords of a floor path's (T, 2) two halves, whatever its
    length."""
    half = len(path) // 2
    a, b = path[half] - path[0], path[-1] - path[half]
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


def scene_lengths(pipe, corpus) -> None:
    """How long the train split's runners side by side last (frames), and how many of them
    reach 4 s as the P-Flow's (140-160 frames) and the S-Flow's crops see them: without
    and with ``repeat_scene_gait`` (the gait carried on, ``scene_gait_periods``)."""
    from umf.train.datasets import SceneDataset

    frames = [r["num_frames"] for r in corpus.scenes.get("train", [])
              if r.get("relation") == "run_side_by_side"]  # fmt: skip
    under = float(np.mean(np.asarray(frames) < 2 * HALF))
    print(f"3. train runners side by side: {len(frames)} scenes, {np.median(frames):.0f} "
          f"frames at the median, {under:.0%} under {2 * HALF}")  # fmt: skip
    for gait in (False, True):
        ds = SceneDataset(corpus, "train", pipe.normalizer, min_frames=140, max_frames=160,
                          mirror=False, seed=0, repeat_gait=gait)  # fmt: skip
        long = sum(ds[i]["features"].shape[1] > 2 * HALF
                   for i, (kind, item, _) in enumerate(ds.items)
                   if kind == "scene" and item.get("relation") == "run_side_by_side")  # fmt: skip
        print(f"3. crops of 140-160 frames, repeat_scene_gait {gait}: {long} reach "
              f"{2 * HALF + 1} frames")  # fmt: skip


def vae_turns(pipe, corpus) -> None:
    """Person 1 of the training crops through the VAE (posterior mean, decoded as the
    pipeline decodes person 1): does the VAE bend a straight runner?"""
    from umf.representation import joints_to_features

    real, back = [], []
    for j in run_crops(pipe, corpus, 2 * HALF):
        f = joints_to_features(torch.from_numpy(j[0]).float())[None]
        z = pipe._encode(f)
        out = pipe.decode(z, f.shape[1])[0]
        joints = out[:, :66].reshape(-1, 22, 3).numpy()
        real.append(turn_deg(j[0, :, 0][:, [0, 2]]))
        back.append(turn_deg(joints[:, 0][:, [0, 2]]))
    for name, t in (("real", real), ("VAE", back)):
        p10, p50, p90 = np.percentile(t, [10, 50, 90])
        print(f"3. training crops ({len(t)}), person 1, {name}: turn p10 / median / p90 "
              f"{p10:+.1f} / {p50:+.1f} / {p90:+.1f} deg")  # fmt: skip


def leader_turns(pipe, seeds: int) -> None:
    """The P-Flow's person 1 alone: a runner of one's own against the pair's leader, and the
    pair's leader at other step budgets and guidance scales."""
    cfg = pipe.config.pflow
    steps, guidance = list(cfg.steps), cfg.guidance
    runs = [("A person runs.", 1, steps, guidance)]
    runs += [("Two people run side by side.", 2, st, g)
             for st, g in ((steps, guidance), ([45, 5], guidance), ([20, 20], guidance),
                           (steps, 1.0), (steps, 3.0))]  # fmt: skip
    for prompt, n, st, g in runs:
        cfg.steps, cfg.guidance = st, g
        turns = []
        for s in range(seeds):
            (scene,) = pipe(prompt, num_people=n, seconds=4.0, seed=s)
            turns.append(turn_deg(np.asarray(scene.joints[0, :, 0])[:, [0, 2]]))
        print(
            f"3. {prompt!r} ({n} people), steps {st}, guidance {g:g}: leader turns "
            + " ".join(f"{t:+.0f}" for t in turns)
            + f" deg, median {np.median(turns):+.0f}"
        )
    cfg.steps, cfg.guidance = steps, guidance


def length_turns(pipe, seeds: int) -> None:
    """Person 1's turn between the halves of its path (raw) against the scene's length: the
    pair's runner leader, a pair's walking leader, and a runner of one's own. The training
    run scenes last 78 frames (2.6 s) at the median."""
    for prompt, n in (("Two people run side by side.", 2), ("Two people walk side by side.", 2),
                      ("A person runs.", 1)):  # fmt: skip
        for seconds in (2.6, 3.0, 4.0, 5.0):
            turns = []
            for s in range(seeds):
                (scene,) = pipe(prompt, num_people=n, seconds=seconds, seed=s, fit=False,
                                separate=False, anchor=False)  # fmt: skip
                turns.append(turn_halves(np.asarray(scene.joints[0, :, 0])[:, [0, 2]]))
            print(f"3. {prompt!r}, {seconds:g} s, raw: leader turns between halves "
                  + " ".join(f"{t:+.0f}" for t in turns)
                  + f" deg, median {np.median(turns):+.0f}")  # fmt: skip


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
    ap.add_argument("--causes", action="store_true",
                    help="also 3.: the runners' scene lengths, the VAE's round trip of them, "
                    "and the P-Flow's leader alone, at other steps and guidance")  # fmt: skip
    args = ap.parse_args()

    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model)
    corpus = Corpus.load(args.corpus)
    training_turns(pipe, corpus)
    generated_turns(pipe, args.seeds)
    if args.causes:
        scene_lengths(pipe, corpus)
        vae_turns(pipe, corpus)
        leader_turns(pipe, args.seeds)
        length_turns(pipe, args.seeds)


if __name__ == "__main__":
    main()
