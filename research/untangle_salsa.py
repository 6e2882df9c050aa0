"""Salsa couples delivered with and without the clean-up's untangling (umf.untangle).

    python research/untangle_salsa.py [--model DIR] [--seeds 32] [--rounds R] [--json FILE]

"Two people dance salsa together.", 4 s, seeds 0..N-1, delivered twice: as the pipeline
delivers it, and with :func:`umf.untangle.untangle` left out of the clean-up. Per run: the
body capsules' overlap (mean depth, frames deeper than 1 cm; :mod:`umf.eval.physics`), the
salsa statistics and targets of ``research/teach_report.py``, the couple's jerk and foot
skating, the largest joint move, and the seconds per scene. ``--rounds``: untangle with
that many push-and-refine rounds instead of :data:`umf.untangle.ROUNDS`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from teach_report import SALSA, closeness, salsa_pass


def couples(pipe, seeds: int) -> tuple[list[np.ndarray], float]:
    """Delivered joints of seeds 0..seeds-1 and the seconds per scene."""
    start = time.perf_counter()
    out = [np.asarray(pipe(SALSA, num_people=2, seconds=4.0, seed=s)[0].joints)
           for s in range(seeds)]  # fmt: skip
    return out, (time.perf_counter() - start) / seeds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import umf.clean_up as clean_up
    from umf.eval.physics import physics_report
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    untangle = clean_up.untangle
    rounds = {} if args.rounds is None else {"rounds": args.rounds}
    runs = {}
    for name in ("without", "with"):
        clean_up.untangle = ((lambda bodies, *a, **k: untangle(bodies, *a, **k, **rounds))
                             if name == "with" else (lambda bodies, *a, **k: bodies))  # fmt: skip
        try:
            scenes, seconds = couples(pipe, args.seeds)
        finally:
            clean_up.untangle = untangle
        rows = []
        for j in scenes:
            c, p = closeness(j), physics_report(j, 30.0)
            rows.append({**c, "pass": salsa_pass(c), "jerk": p["jerk"],
                         "skate_ratio": p["skate_ratio"]})  # fmt: skip
        runs[name] = {"seconds_per_scene": seconds, "seeds": rows, "joints": scenes}
    pairs = zip(runs["with"]["joints"], runs["without"]["joints"], strict=True)
    moved = [float(np.abs(a - b).max()) for a, b in pairs]
    print(f"{args.seeds} seeds, 4 s, delivered; mean over seeds (median)")
    keys = ("penetration_cm", "penetration_frac", "hands_near", "pelvis", "facing", "jerk",
            "skate_ratio")  # fmt: skip
    print(f"{'':8s}" + "".join(f"{k:>22s}" for k in keys) + "   passing   s/scene")
    for name, run in runs.items():
        values = {k: [r[k] for r in run["seeds"]] for k in keys}
        cells = "".join(f"{np.mean(v):13.3f} ({np.median(v):6.3f})" for v in values.values())
        passing = sum(r["pass"] for r in run["seeds"])
        print(f"{name:8s}{cells}   {passing:3d}/{args.seeds}   {run['seconds_per_scene']:.3f}")
    print(f"largest joint move per seed (m): median {np.median(moved):.3f}, max {max(moved):.3f}; "
          f"seeds untouched {sum(m == 0 for m in moved)} of {args.seeds}")  # fmt: skip
    if args.json is not None:
        for run in runs.values():
            run.pop("joints")
        args.json.write_text(json.dumps({"runs": runs, "moved_m": moved}, indent=1) + "\n")


if __name__ == "__main__":
    main()
