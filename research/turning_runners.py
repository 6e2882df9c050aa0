"""Runners beside a turning leader, seen from above: with and without ``sflow.warm_follow``.

    python research/turning_runners.py [--model DIR] [--seeds 7 13] [--out FILE.png]

For each seed, "Two people run side by side." (4 s, delivered) from the model as it is and
from the same model with ``sflow.warm_follow`` off: every person's pelvis path on the floor,
a dot where they start, and how far person 2 ends ahead of person 1 along person 1's
start-to-end chord (``research/keep_pace.py``'s measure; negative: behind).
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np

PROMPT = "Two people run side by side."


def floor_paths(joints: np.ndarray) -> np.ndarray:
    """(N, T, 2) pelvis paths (x, z) of joints (N, T, 22, 3)."""
    return np.asarray(joints)[:, :, 0][..., [0, 2]]


def ends_ahead(paths: np.ndarray) -> list[float]:
    """How far each person 2..N ends ahead of person 1 along person 1's chord (m)."""
    chord = paths[0, -1] - paths[0, 0]
    heading = chord / max(float(np.linalg.norm(chord)), 1e-6)
    return [float((p[-1] - paths[0, -1]) @ heading) for p in paths[1:]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 13])
    ap.add_argument("--out", type=Path, default=Path("turning-runners.png"))
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    follow = pipe.config.sflow.warm_follow
    fig, axes = plt.subplots(2, len(args.seeds), figsize=(3.2 * len(args.seeds), 6.4),
                             squeeze=False)  # fmt: skip
    original = copy.deepcopy(pipe.config.sflow)
    for row, value in enumerate((None, follow)):
        pipe.config.sflow.warm_follow = value
        for col, seed in enumerate(args.seeds):
            (scene,) = pipe(PROMPT, num_people=2, seconds=4.0, seed=seed)
            paths = floor_paths(scene.joints)
            ax = axes[row][col]
            for k, (p, c) in enumerate(zip(paths, ("tab:blue", "tab:red"), strict=False)):
                ax.plot(p[:, 0], p[:, 1], color=c, label=f"P{k + 1}")
                ax.plot(*p[0], "o", color=c, ms=4)
            ahead = ends_ahead(paths)[0]
            ax.set_title(f"seed {seed}, warm_follow {value}\nP2 ends {ahead:+.2f} m", fontsize=8)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            print(f"seed {seed} warm_follow {value}: P2 ends {ahead:+.2f} m ahead")
    pipe.config.sflow = original
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"{PROMPT} (4 s, delivered, {pipe.name}; x, z in m)", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
