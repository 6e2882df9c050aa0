"""How well the mocap importer maps each library's skeleton onto SMPL-22, and how fast.

    python research/mocap_report.py DIR [DIR ...] [--out FILE]

For each ``--mocap``-style folder: clips read per second (files parsed, forward kinematics,
mapping, resampling), and per skeleton the mapping's fidelity against the source's own
forward kinematics:
- ``direct_mm``: the largest distance between a directly mapped SMPL joint and the source
  joint it names (0 up to float rounding: the mapping reads FK positions, it does not move them);
- ``placed_mm``: how far the placed joints (midpoints, End Sites, DeepMimic's derived
  spine/collar/head/toe joints) are from the straight chain they are placed on, median;
- ``bone_cv_pct``: the median over bones of each bone's length variation over frames
  (standard deviation over mean): 0 for a rigid source skeleton mapped joint to joint;
- ``fit_mm``: mean distance between the mapped joints and one rigid SMPL-22 body fitted to
  them (umf.kinematics, what every export writes): what the rigid-body view changes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def bone_cv(j: np.ndarray) -> float:
    from umf.skeleton import PARENTS

    lengths = np.stack([np.linalg.norm(j[:, k] - j[:, p], axis=-1)
                        for k, p in enumerate(PARENTS) if p >= 0], axis=1)  # fmt: skip
    return float(np.median(lengths.std(0) / np.maximum(lengths.mean(0), 1e-9)) * 100)


def direct_error(path: Path, skeleton) -> float:
    """Largest distance (file units -> m) between mapped joints and the source FK joints."""
    from umf.bvh import forward_kinematics, read_bvh
    from umf.data.mocap import read_motion
    from umf.data.skeletons import normal_name, recognise

    if path.suffix.lower() != ".bvh":
        return 0.0
    bvh = read_bvh(path)
    table = skeleton if skeleton is not None and skeleton.sources else recognise(bvh.names)
    pos, _ = forward_kinematics(bvh)
    raw = read_motion(path, skeleton)
    off = pos.shape[0] - raw.joints.shape[0]  # a dropped reference frame
    index = {normal_name(n): i for i, n in enumerate(bvh.names)}
    worst = 0.0
    for k, src in enumerate(table.sources):
        if isinstance(src, str) and not src.startswith("end:"):
            d = np.linalg.norm(raw.joints[:, k] - pos[off:, index[normal_name(src)]], axis=-1)
            worst = max(worst, float(d.max()))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from umf.data.mocap import load_mocap, scan_library
    from umf.kinematics import fit_bodies

    report = {}
    for d in args.dirs:
        t0 = time.perf_counter()
        problems: list = []
        clips = list(load_mocap(d, problems))
        seconds = time.perf_counter() - t0
        lib = scan_library(d)
        files = sum(len(c.meta["file"].split(",")) for c in clips)
        by_skel: dict[str, dict] = {}
        for c in clips[:40]:
            s = by_skel.setdefault(c.meta["skeleton"], {"cv": [], "fit": [], "direct": []})
            for p in range(c.num_people):
                j = c.joints[p]
                s["cv"].append(bone_cv(j))
                bodies = fit_bodies(j[None].astype(np.float64), bones="fit")
                s["fit"].append(float(np.linalg.norm(bodies.joints()[0] - j, axis=-1).mean()))
            first = d / c.meta["file"].split(",")[0]
            s["direct"].append(direct_error(first, lib.skeleton) * c.meta["unit"])
        report[d.name] = {
            "clips": len(clips), "files": files, "skipped": len(problems),
            "seconds": round(seconds, 2), "clips_per_s": round(len(clips) / seconds, 1),
            "files_per_s": round(files / seconds, 1),
            "frames_30fps": int(sum(c.num_frames * c.num_people for c in clips)),
            "skeletons": {k: {"direct_mm": round(max(v["direct"]) * 1000, 4),
                              "bone_cv_pct": round(float(np.median(v["cv"])), 3),
                              "fit_mm": round(float(np.median(v["fit"])) * 1000, 2)}
                          for k, v in by_skel.items()},
        }  # fmt: skip
        r = report[d.name]
        print(f"{d.name}: {r['clips']} clips ({r['files']} files) in {r['seconds']} s = "
              f"{r['files_per_s']} files/s; skipped {r['skipped']}")  # fmt: skip
        for k, v in r["skeletons"].items():
            print(f"  {k:12s} direct {v['direct_mm']:.4f} mm, bone length variation "
                  f"{v['bone_cv_pct']:.3f} %, rigid fit {v['fit_mm']:.2f} mm")  # fmt: skip
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
