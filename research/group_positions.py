"""Where people 2..N stand relative to person 1: a quick look at a group prompt, seed by seed.

    python research/group_positions.py "Three people walk in single file." --people 3
        [--model DIR] [--seeds 4] [--seconds 4]

For each seed and each person k >= 2 of the delivered scene: how far to person 1's left
(+) or right (-) and how far ahead (+) or behind (-) along person 1's heading they stand,
at the first frame and at the last (``umf.data.relations.lateral_offset``, person 1's
heading at that frame).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def positions(joints: np.ndarray) -> list[tuple[float, float, float, float]]:
    """(left at start, left at end, ahead at start, ahead at end) of each person k >= 2 of a
    scene (N, T, 22, 3), metres, relative to person 1."""
    from umf.data.relations import lateral_offset

    out = []
    for k in range(1, joints.shape[0]):
        l0, f0 = lateral_offset(joints, 0, k, 0)
        l1, f1 = lateral_offset(joints, 0, k, joints.shape[1] - 1)
        out.append((float(l0), float(l1), float(f0), float(f1)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("prompt")
    ap.add_argument("--people", type=int, default=3)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=4.0)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    print(f"{pipe.name}: {args.prompt!r}, {args.people} people, {args.seconds:g} s, delivered;"
          " left / ahead of person 1 (m), start -> end")  # fmt: skip
    for s in range(args.seeds):
        (scene,) = pipe(args.prompt, num_people=args.people, seconds=args.seconds, seed=s)
        people = [
            f"P{k} left {l0:+.2f} -> {l1:+.2f}, ahead {f0:+.2f} -> {f1:+.2f}"
            for k, (l0, l1, f0, f1) in enumerate(positions(np.asarray(scene.joints)), 2)
        ]
        print(f"seed {s}: " + " | ".join(people))


if __name__ == "__main__":
    main()
