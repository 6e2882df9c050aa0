"""Does each person of a generated pair move like a real one? Body statistics per person.

For the first K two-person scenes of a split: the real people, person 2 generated around
the real person 1 (react mode), and both people generated from the caption (P-Flow person
1, S-Flow person 2), raw output (no anchoring, no fit) and person 2 as the pipeline
delivers it, 5 s. Per row, medians over the
scenes of ``umf.eval.motion_stats`` statistics (pelvis travel speed, root-relative ankle and
wrist speed, head drop) and the mean joint acceleration. A person carried along a path in
a still pose has a real pelvis speed and almost no ankle or wrist speed.

    python research/pair_motion_stats.py [MODEL_DIR] [--split val] [--scenes 64]
"""

from __future__ import annotations

import argparse

import numpy as np

from umf.data.clip import FPS
from umf.data.corpus import Corpus
from umf.eval.motion_stats import median_statistics
from umf.eval.physics import jitter
from umf.pipeline import UMFPipeline, delivered_joints
from umf.representation import CONTACT

FRAMES = 150
STATS = ("pelvis_speed", "ankle_energy", "wrist_energy", "head_drop")


def row(people: list[np.ndarray], fps: float) -> list[float]:
    """Medians over people (T, 22, 3) of STATS and the acceleration."""
    accel = float(np.median([jitter(j, fps)["accel"] for j in people]))
    return [*median_statistics(people, STATS, fps), accel]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("model", nargs="?", default="src/umf/assets/model")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--split", default="val")
    ap.add_argument("--scenes", type=int, default=64)
    args = ap.parse_args()
    corpus = Corpus.load(args.corpus)
    recipes = [r for r in corpus.scenes[args.split] if r["num_people"] == 2][: args.scenes]
    real = [corpus.scene_joints(r)[:, :FRAMES] for r in recipes]
    pipe = UMFPipeline.from_pretrained(args.model)
    fps = pipe.config.fps
    react, full, delivered = [], [], []
    for k, (r, j) in enumerate(zip(recipes, real, strict=True)):
        react.append(pipe(r["captions"][0], num_people=2, seed=k, actor=j[0].astype(np.float32),
                          separate=False, fit=False)[0].joints)  # fmt: skip
        scene = pipe(r["captions"][0], num_people=2, seconds=(FRAMES - 1) / fps, seed=k,
                     separate=False, fit=False)[0]  # fmt: skip
        full.append(scene.joints)
        contacts = np.ascontiguousarray(scene.features[..., CONTACT])
        delivered.append(delivered_joints(scene.raw_joints, contacts))
    rows = {
        "real person 1": row([j[0] for j in real], FPS),
        "real person 2": row([j[1] for j in real], FPS),
        "person 2 around the real person 1 (S-Flow)": row([s[1] for s in react], fps),
        "person 1, generated (P-Flow)": row([s[0] for s in full], fps),
        "person 2, generated (S-Flow)": row([s[1] for s in full], fps),
        "person 2, generated, as delivered (feet anchored, fitted)": row(
            [s[1] for s in delivered], fps
        ),
    }
    print(f"{pipe.name}: {len(recipes)} {args.split} pair scenes, {FRAMES} frames, raw output; "
          "medians over scenes (speeds m/s, head drop m, acceleration m/s²)\n")  # fmt: skip
    print("| person | " + " | ".join(STATS) + " | acceleration |")
    print("|---|" + "---:|" * (len(STATS) + 1))
    for name, v in rows.items():
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in v) + " |")


if __name__ == "__main__":
    main()
