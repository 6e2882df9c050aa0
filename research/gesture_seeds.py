"""Per-seed gesture statistics of a model: what a user gets for seeds 0-7, 4 s, one person.

For raised hands (lower wrist above the head), a bow (head drop), a right-hand wave
(right wrist above the head, and its side-to-side swings a second) and a walk (pelvis
speed: how much the seeds differ), the value of each seed and the median, on the fitted
joints a user's files hold (``scene.joints``).

    python research/gesture_seeds.py [MODEL_DIR ...]      # default: the bundled model
"""

from __future__ import annotations

import sys

import numpy as np

from umf.eval.motion_stats import motion_statistics
from umf.pipeline import UMFPipeline

GESTURES = (
    ("A person raises both hands.", ("both_wrists_above_head",)),
    ("Someone bows politely.", ("head_drop",)),
    ("Someone waves with the right hand.", ("right_wrist_above_head", "right_wrist_swings")),
    ("A person walks forward.", ("pelvis_speed",)),
)


def main() -> None:
    for path in sys.argv[1:] or [None]:
        pipe = UMFPipeline.from_pretrained(path)
        for prompt, stats in GESTURES:
            scenes = [pipe(prompt, num_people=1, seconds=4.0, seed=s)[0] for s in range(8)]
            rows = [motion_statistics(sc.joints[0]) for sc in scenes]
            for stat in stats:
                v = [row[stat] for row in rows]
                print(f"{pipe.name} | {stat} | {' '.join(f'{x:.2f}' for x in v)} | "
                      f"median {np.median(v):.3f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
