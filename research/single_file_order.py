"""Whether a single file walks in order, seed by seed, with and without ``sflow.warm_extend``.

    python research/single_file_order.py [--model DIR] [--seeds 8] [--figure PNG]

For "Six people walk in single file." (1.6 s) and "Five people walk in single file." (2 s),
raw (no separation), seeds 0..N-1: how far each person k >= 2 starts ahead (+) or behind (-)
person 1 along person 1's heading (``umf.data.relations.lateral_offset``), and whether each
starts behind the one before (:func:`in_order`). The val groups' single files that failed
their ``order`` check were short files of six (results/umf-small-bandai-20261217).
``--figure`` draws, seen from above, the pelvis tracks of the six at 1.6 s for the first
four seeds, without and with the option, numbered at their start.
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


def tracks(joints: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each person's pelvis floor track (x to person 1's right, y along their heading, m)
    of a scene (N, T, 22, 3), person 1 starting at the origin."""
    from umf.data.relations import facing_dirs

    f = facing_dirs(joints[0, 0])
    left = np.array([f[1], -f[0]])
    out = []
    for person in joints:
        d = person[:, 0, [0, 2]] - joints[0, 0, 0, [0, 2]]
        out.append((-(d @ left), d @ f))
    return out


def draw(scenes: dict[bool, list[np.ndarray]], path: Path) -> None:
    """Pelvis floor tracks (:func:`tracks`) of each scene, one column per seed, a row per
    setting, seen from above: person 1's left drawn on the left, heading up the page."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    drawn = {k: [tracks(j) for j in js] for k, js in scenes.items()}
    wide = 0.5 + max(float(np.abs(x).max()) for ts in drawn.values() for t in ts for x, _ in t)
    cols = len(scenes[False])
    fig, axes = plt.subplots(2, cols, figsize=(2.4 * cols, 5.6), squeeze=False)
    for row, extend in enumerate((False, True)):
        for col, (joints, people) in enumerate(zip(scenes[extend], drawn[extend], strict=True)):
            ax = axes[row, col]
            for k, (x, y) in enumerate(people):
                ax.plot(x, y, lw=1.5)
                ax.annotate(str(k + 1), (x[0], y[0]), fontsize=8, ha="center", va="top")
            ordered = in_order(ahead_of_leader(joints))
            ax.set_title(f"seed {col}: {'in order' if ordered else 'out of order'}", fontsize=8)
            ax.set_xlim(-wide, wide)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
            if row == 1:
                ax.set_xlabel("m to person 1's right", fontsize=7)
        axes[row, 0].set_ylabel(f"warm_extend {str(extend).lower()}\nm along person 1's heading",
                                fontsize=8)  # fmt: skip
    fig.suptitle(f"{FILES[0][0]!r}, {FILES[0][2]} s, raw, seen from above", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    drawn: dict[bool, list[np.ndarray]] = {False: [], True: []}
    for extend in (False, True):
        pipe.config.sflow.warm_extend = extend
        for prompt, n, seconds in FILES:
            rows = []
            for seed in range(args.seeds):
                (scene,) = pipe(prompt, num_people=n, seconds=seconds, seed=seed, fit=False,
                                separate=False)  # fmt: skip
                rows.append(ahead_of_leader(np.asarray(scene.joints)))
                if prompt == FILES[0][0] and seed < 4:
                    drawn[extend].append(np.asarray(scene.joints))
            ok = sum(in_order(r) for r in rows)
            print(f"warm_extend {str(extend).lower():5s} {prompt!r} {seconds} s: in order "
                  f"{ok}/{len(rows)}; ahead of person 1 (m), seed by seed: "
                  f"{[np.round(r, 1).tolist() for r in rows]}")  # fmt: skip
    if args.figure is not None:
        draw(drawn, args.figure)


if __name__ == "__main__":
    main()
