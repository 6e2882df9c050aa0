"""How fast the people of the composed paced scenes the S-Flow trains on move, by crop length.

    python research/paced_training_speeds.py CORPUS [--relation run_side_by_side]

For each crop length (feature frames), the train scenes of one paced relation long enough
for it (cropped as the S-Flow's loader crops them, in person 1's frame, not mirrored): how
many there are, the median start-to-end floor speed of the leader and of person 2, and
person 2's speed by quarter of the crop; then the scenes' lengths (10th, 50th, 90th
percentile) and, for the relation's single clips (``--content``), their speed over their
first 4 s (or whole length). The generated leader's speed is in ``research/keep_pace.py``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--relation", default="run_side_by_side")
    ap.add_argument("--content", default="run", help="the single clips' action to compare")
    ap.add_argument("--lengths", type=int, nargs="+", default=[60, 90, 120])
    args = ap.parse_args()

    from umf.data.corpus import Corpus
    from umf.representation import features_to_joints
    from umf.train.datasets import SceneDataset

    corpus = Corpus.load(args.corpus)
    fps = 30.0
    for frames in args.lengths:
        ds = SceneDataset(corpus, "train", None, min_frames=frames, max_frames=frames,
                          mirror=False, seed=0, real_clips=False)  # fmt: skip
        ds.items = [it for it in ds.items if it[1].get("relation") == args.relation]
        lead, other, quarters = [], [], []
        for i in range(len(ds)):
            f = ds[i]["features"]
            if f.shape[1] != frames:
                continue
            p = features_to_joints(f).numpy()[:, :, 0][..., [0, 2]]
            v = np.linalg.norm(p[:, -1] - p[:, 0], axis=-1) / ((frames - 1) / fps)
            lead.append(v[0])
            other.append(v[1])
            step = np.linalg.norm(np.diff(p[1], axis=0), axis=-1) * fps
            q = frames // 4
            quarters.append([step[k * q : (k + 1) * q].mean() for k in range(4)])
        if not lead:
            print(f"{frames} frames: no {args.relation} train scene is this long")
            continue
        by_quarter = [round(float(x), 2) for x in np.median(quarters, axis=0)]
        print(f"{frames} frames ({frames / fps:.1f} s): {len(lead)} scenes; leader "
              f"{np.median(lead):.2f} m/s, person 2 {np.median(other):.2f} m/s (medians); "
              f"person 2 by quarter {by_quarter}")  # fmt: skip
    scenes = corpus.scenes["train"]
    lengths = [r["num_frames"] for r in scenes if r.get("relation") == args.relation]
    print(f"{args.relation} train scenes: {len(lengths)}, frames (10/50/90th percentile) "
          f"{np.percentile(lengths, [10, 50, 90]).round().tolist()}")  # fmt: skip
    speeds = []
    for clip in corpus.clips:
        if clip.num_people == 1 and clip.meta.get("content") == args.content:
            p = clip.joints[0][:, 0][:, [0, 2]]
            n = min(len(p), int(4 * fps) + 1)
            speeds.append(np.linalg.norm(p[n - 1] - p[0]) / ((n - 1) / fps))
    if speeds:
        print(f"single '{args.content}' clips: {len(speeds)}, speed over their first 4 s: "
              f"median {np.median(speeds):.2f}, 90th percentile "
              f"{np.percentile(speeds, 90):.2f} m/s")  # fmt: skip


if __name__ == "__main__":
    main()
