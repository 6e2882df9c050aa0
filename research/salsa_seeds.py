"""A salsa couple seed by seed: the "teach it" issue's salsa targets on one model, fast.

    python research/salsa_seeds.py [MODEL_DIR] [--seeds 8]

"Two people dance salsa together.", 4 s, delivered: per seed the closeness statistics of
``research/teach_report.py`` (nearest hands within 0.3 x stature: the share of frames;
pelvises apart in statures; facing: the median cosine), then their medians and the seeds
passing every target. ``teach_report.py`` measures the real takes beside them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from teach_report import SALSA, closeness, salsa_pass


def salsa_couples(model: Path | None, seeds: int):
    """(seed, joints (2, T, 22, 3) as delivered) of "Two people dance salsa together.", 4 s,
    seeds 0..seeds-1, from the model directory (None: the bundled model)."""
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    for s in range(seeds):
        (scene,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
        yield s, np.asarray(scene.joints, dtype=np.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path, nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()

    rows = []
    for s, joints in salsa_couples(args.model, args.seeds):
        c = closeness(joints)
        rows.append(c)
        print(s, {k: round(v, 3) if isinstance(v, float) else v for k, v in c.items()},
              salsa_pass(c))  # fmt: skip
    for k in ("hands_near", "pelvis", "facing"):
        print(k, "median", round(float(np.median([r[k] for r in rows])), 3))
    print("passing", sum(salsa_pass(r) for r in rows), f"/ {args.seeds}")


if __name__ == "__main__":
    main()
