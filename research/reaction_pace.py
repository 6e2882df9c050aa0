"""Why followers fall behind a walking leader: the training scenes, the legs, the fusion.

    python research/reaction_pace.py [--model DIR] [--corpus out/corpus] [--seeds 6]

Three suspects of the "reactions that keep up" issue, one measurement each:
- the training data: in the corpus's composed side-by-side scenes (first 4 s of 60 train
  scenes per relation), person 2's floor speed over person 1's, how many are within 20 %,
  and how many end more than 1 m ahead or behind (the issue's targets, on the data itself);
  and the VAE alone: person 2 of 16 of them encoded and decoded, its slower foot's speed;
- the legs: generated "Two people walk side by side." (seeds 0..N-1), each person's slower
  foot's median floor speed on the decoded positions (a planted foot is near 0; a body that
  glides carries both feet along), and person 2's decoded and delivered speed over the
  leader's;
- the decoding: the same with people 2..N fused like person 1 (``vae.reaction_root_fusion``
  set to ``vae.root_fusion``), which trusts the decoded velocities over the positions;
- the leader: with ``--corpus``, person 2 reacting to real walkers (the first 4 s of 8 test
  clips labelled walk, ``umf react``, seed 0), the same speeds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

WALK = "Two people walk side by side."
FPS = 30.0


def floor_speed(j: np.ndarray) -> float:
    """Start-to-end floor speed (m/s) of one person's pelvis (T, 22, 3)."""
    p = j[:, 0, [0, 2]]
    return float(np.linalg.norm(p[-1] - p[0]) / ((len(p) - 1) / FPS))


def slower_foot(j: np.ndarray) -> float:
    """Median over frames of the slower foot's floor speed (m/s)."""
    feet = j[:, [10, 11]][..., [0, 2]]
    speed = np.linalg.norm(np.diff(feet, axis=0), axis=-1) * FPS
    return float(np.median(speed.min(axis=1)))


def training_scenes(corpus_dir: Path, pipe=None, scenes: int = 60) -> None:
    from umf.data.corpus import Corpus
    from umf.representation import features_to_joints
    from umf.train.datasets import crop_recipe

    corpus = Corpus.load(corpus_dir)
    for relation in ("walk_side_by_side", "run_side_by_side"):
        ratios, ahead = [], []
        chosen = [r for r in corpus.scenes["train"] if r.get("relation") == relation][:scenes]
        for recipe in chosen:
            crop = crop_recipe(recipe, corpus.actors(), 0, int(4 * FPS) + 1)
            j = features_to_joints(torch.from_numpy(corpus.scene_features(crop))).numpy()
            p = j[:, :, 0, [0, 2]]
            travel = np.linalg.norm(p[:, -1] - p[:, 0], axis=-1)
            forward = (p[0, -1] - p[0, 0]) / max(travel[0], 1e-6)
            ratios.append(travel[1] / travel[0])
            ahead.append(float(np.dot(p[1, -1] - p[0, -1], forward)))
        r, a = np.array(ratios), np.array(ahead)
        q1, q3 = np.percentile(r, [25, 75])
        print(f"training scenes, {relation} ({len(r)}): person 2 / person 1 speed median "
              f"{np.median(r):.2f} (IQR {q1:.2f}-{q3:.2f}); within 20 %: "
              f"{np.mean(np.abs(r - 1) <= 0.2):.0%}; more than 1 m ahead or behind at 4 s: "
              f"{np.mean(np.abs(a) > 1.0):.0%}")  # fmt: skip
        if pipe is not None:  # the VAE alone: person 2 of the same scenes encoded and decoded
            feet = []
            for recipe in chosen[:16]:
                crop = crop_recipe(recipe, corpus.actors(), 0, int(4 * FPS) + 1)
                f = torch.from_numpy(corpus.scene_features(crop)).float()[1:2]
                with torch.no_grad():
                    back = pipe.decode(pipe._encode(f), f.shape[1], reaction=True)
                feet.append((slower_foot(features_to_joints(f)[0].numpy()),
                             slower_foot(features_to_joints(back)[0].numpy())))  # fmt: skip
            real_feet, vae_feet = np.median(np.array(feet), axis=0)
            print(
                f"  person 2's slower foot, {len(feet)} of them: real {real_feet:.2f} m/s, "
                f"the VAE's reconstruction {vae_feet:.2f} m/s"
            )


def generated(model: Path | None, seeds: int) -> None:
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    vae = pipe.config.vae
    fusions = (("as shipped", vae.reaction_root_fusion), ("fused like person 1", vae.root_fusion))
    for name, fusion in fusions:
        vae.reaction_root_fusion = fusion
        rows = []
        for s in range(seeds):
            (scene,) = pipe(WALK, num_people=2, seconds=4.0, seed=s)
            raw, out = np.asarray(scene.raw_joints), np.asarray(scene.joints)
            rows.append((slower_foot(raw[0]), slower_foot(raw[1]),
                         floor_speed(raw[1]) / floor_speed(raw[0]),
                         floor_speed(out[1]) / floor_speed(out[0])))  # fmt: skip
        lead, follow, decoded, delivered = np.median(np.array(rows), axis=0)
        print(f"generated, people 2..N {name} (reaction_root_fusion {fusion:g}), {seeds} "
              f"seeds: slower foot leader {lead:.2f} m/s, person 2 {follow:.2f} m/s; person 2 / "
              f"leader speed decoded {decoded:.2f}, delivered {delivered:.2f}")  # fmt: skip


def real_leaders(model: Path | None, corpus_dir: Path, clips: int = 8) -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    walks = [c for c in Corpus.load(corpus_dir).split_clips("test")
             if c.meta.get("content") == "walk" and c.num_frames > 4 * FPS][:clips]  # fmt: skip
    rows = []
    for clip in walks:
        actor = clip.joints[0, : int(4 * FPS) + 1]
        (scene,) = pipe(WALK, num_people=2, seed=0, actor=actor)
        raw, out = np.asarray(scene.raw_joints), np.asarray(scene.joints)
        rows.append((slower_foot(raw[1]), floor_speed(raw[1]) / floor_speed(out[0]),
                     floor_speed(out[1]) / floor_speed(out[0])))  # fmt: skip
    follow, decoded, delivered = np.median(np.array(rows), axis=0)
    print(
        f"reactions to {len(rows)} real walkers: slower foot of person 2 {follow:.2f} m/s; "
        f"person 2 / leader speed decoded {decoded:.2f}, delivered {delivered:.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args()
    if args.corpus is not None:
        from umf.pipeline import UMFPipeline

        training_scenes(args.corpus, UMFPipeline.from_pretrained(args.model))
    generated(args.model, args.seeds)
    if args.corpus is not None:
        real_leaders(args.model, args.corpus)


if __name__ == "__main__":
    main()
