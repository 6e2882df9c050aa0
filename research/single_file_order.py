"""Whether a single file walks in order, seed by seed, with and without ``sflow.warm_extend``.

    python research/single_file_order.py [--model DIR] [--seeds 8]

For "Six people walk in single file." (1.6 s) and "Five people walk in single file." (2 s),
raw (no separation), seeds 0..N-1: how far each person k >= 2 starts ahead (+) or behind (-)
person 1 along person 1's heading (``umf.data.relations.lateral_offset``), and whether each
starts behind the one before (:func:`in_order`). The val groups' single files that failed
their ``order`` check were short files of six (results/umf-small-bandai-20261217).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

FILES = (("Six people walk in single file.", 6, 1.6), ("Five people walk in single file.", 5, 2.0))


def ahead_of_leader(joints: np.ndarray) -> list[float]:
    """Metres each person k >= 2 of a scene (N, T, 22, 3) starts ahead of person 1."""
    from umf.data.relations import lateral_offset

    return [float(lateral_offset(joints, 0, k, 0)[1]) for k in range(1, joints.shape[0])]


def in_order(ahead: list[float]) -> bool:
    """Person 2 behind person 1 and each next person behind the one before."""
    return bool(ahead) and ahead[0] < 0 and bool(np.all(np.diff(ahead) < 0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    for extend in (False, True):
        pipe.config.sflow.warm_extend = extend
        for prompt, n, seconds in FILES:
            rows = []
            for seed in range(args.seeds):
                (scene,) = pipe(prompt, num_people=n, seconds=seconds, seed=seed, fit=False,
                                separate=False)  # fmt: skip
                rows.append(ahead_of_leader(np.asarray(scene.joints)))
            ok = sum(in_order(r) for r in rows)
            print(f"warm_extend {str(extend).lower():5s} {prompt!r} {seconds} s: in order "
                  f"{ok}/{len(rows)}; ahead of person 1 (m), seed by seed: "
                  f"{[np.round(r, 1).tolist() for r in rows]}")  # fmt: skip


if __name__ == "__main__":
    main()
