"""Would placing a generated salsa couple as close as the real takes make them hold hands?

    python research/salsa_pull_in.py [MODEL_DIR] [--pelvis 0.515] [--clearance 0.05]

"Two people dance salsa together.", 4 s, seeds 0-7, as delivered. Person 2 is moved rigidly
on the floor towards person 1 (along their median pelvis-to-pelvis line, 2 cm at a time)
until their pelvises are ``--pelvis`` statures apart at the median (the CMU train takes'
median: 0.515, results/umf-small-bandai-20261207) or some two joints of theirs would come
closer than ``--clearance`` m. Per seed: how far they moved and the salsa statistics of
``research/teach_report.py`` before and after. A clean-up that only places people cannot
do more than this.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from salsa_seeds import salsa_couples
from teach_report import closeness, salsa_pass


def pulled_in(j: np.ndarray, pelvis: float, clearance: float) -> tuple[np.ndarray, float]:
    """Joints (2, T, 22, 3) with person 2 moved towards person 1, and how far (m)."""
    from umf.data.relations import stature

    size = 0.5 * (stature(j[0]) + stature(j[1]))
    gap = j[1, :, 0][:, [0, 2]] - j[0, :, 0][:, [0, 2]]
    way = -np.median(gap, axis=0)
    way /= max(float(np.linalg.norm(way)), 1e-9)
    best = 0.0
    for step in np.arange(0.02, 3.0, 0.02):
        m = j.copy()
        m[1, ..., 0] += way[0] * step
        m[1, ..., 2] += way[1] * step
        apart = np.median(np.linalg.norm(m[1, :, 0][:, [0, 2]] - m[0, :, 0][:, [0, 2]], axis=-1))
        closest = np.linalg.norm(m[0][:, :, None] - m[1][:, None], axis=-1).min()
        if apart / size < pelvis or closest < clearance:
            break
        best = float(step)
    out = j.copy()
    out[1, ..., 0] += way[0] * best
    out[1, ..., 2] += way[1] * best
    return out, best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path, nargs="?", default=None)
    ap.add_argument("--pelvis", type=float, default=0.515)
    ap.add_argument("--clearance", type=float, default=0.05)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()

    rows = []
    for s, j in salsa_couples(args.model, args.seeds):
        m, moved = pulled_in(j, args.pelvis, args.clearance)
        a, b = closeness(j), closeness(m)
        rows.append(b)
        print(f"seed {s}: moved {moved:.2f} m; hands near {a['hands_near']:.2f} -> "
              f"{b['hands_near']:.2f}, pelvises {a['pelvis']:.2f} -> {b['pelvis']:.2f} "
              f"statures, facing {b['facing']:.2f}, overlap {b['penetration_frac']:.3f}; "
              f"passes {salsa_pass(b)}")  # fmt: skip
    print("hands near, median", round(float(np.median([r["hands_near"] for r in rows])), 3),
          "| passing", sum(salsa_pass(r) for r in rows), f"/ {args.seeds}")  # fmt: skip


if __name__ == "__main__":
    main()
