"""How close real composed groups come: for each person k >= 3 of the 100 val groups
(``research/group_checks.py``'s), the closest any of their joints comes to a joint of
someone before them, over every frame (m), by relation. ``sflow.warm_clear`` was read
against these.

    python results/umf-small-bandai-20261215/tried/real_group_gaps.py CORPUS
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))

from group_checks import val_groups


def main() -> None:
    from umf.data.corpus import Corpus
    from umf.data.relations import closest_joints
    from umf.eval.relations import real_scene_joints

    corpus = Corpus.load(Path(sys.argv[1]))
    records = val_groups(corpus, 100)
    by: dict[str, list[float]] = {}
    for r, j in zip(records, real_scene_joints(corpus, records), strict=True):
        for k in range(2, j.shape[0]):
            gap = min(closest_joints(j[k], j[i])[0] for i in range(k))
            by.setdefault(r["relation"], []).append(gap)
    every = np.concatenate([np.asarray(v) for v in by.values()])
    print("percentiles 5 / 10 / 25 / 50 (m)")
    print("all people k >= 3:", np.percentile(every, [5, 10, 25, 50]).round(3))
    for name, gaps in sorted(by.items()):
        print(f"{name}:", np.percentile(gaps, [5, 10, 25, 50]).round(3))


if __name__ == "__main__":
    main()
