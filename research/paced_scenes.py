"""Facts about the paced side-by-side scenes quoted on results/umf-small-bandai-20261204:

    python research/paced_scenes.py --corpus out/corpus [--against OTHER/corpus]

- the side checks of the test pairs: how many ask for the left and the right, and how many
  of those scenes' captions name a side (none: the model can only guess);
- the fallback partner (the leader's own clip): for each sample walk clip, the gap between
  the two people at the first and the last frame, when the copy is mirrored (the first
  version) and when it starts a stride later (the composer now);
- how many paced training scenes play a clip mirrored beside itself (the first fallback);
- with ``--against``: how many scenes of each split differ between two corpora.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "bandai-sample"


def side_checks(corpus: Path) -> None:
    scenes = json.loads((corpus / "scenes.json").read_text())["test"]
    count: Counter = Counter()
    for r in scenes:
        named = any(w in " ".join(r["captions"]).lower() for w in ("left", "right"))
        for c in r["constraints"]:
            if c["type"] == "side":
                count[(c["side"], named)] += 1
    print("test pairs' side checks (side, a caption names a side):", dict(count))


def mirrored_fallbacks(corpus: Path) -> None:
    from umf.data.scene_relations import PACED

    scenes = json.loads((corpus / "scenes.json").read_text())["train"]
    hits = [r for r in scenes if r["relation"] in PACED
            and any(p["mirrored"] for p in r["people"])]  # fmt: skip
    print(f"paced training scenes with a mirrored copy: {len(hits)} of {len(scenes)} scenes")


def fallback_gaps() -> None:
    from umf.data.bandai import load_bandai
    from umf.data.pace import left_strides
    from umf.data.scenes import Actor, build_scene

    for c in load_bandai(SAMPLE):
        if c.meta["content"] != "walk" or c.num_frames < 120:
            continue
        a = Actor.from_joints(c.id, c.joints[0], "walk", c.meta["style"])
        s = left_strides(a.joints)
        for name, people in (
            ("mirrored copy", [(0, False, 0.0), (0, True, 0.8)]),
            ("a stride later", [(int(s[0]), False, 0.0), (int(s[1]), False, 0.8)]),
        ):
            n = min(len(a.joints) - start for start, _, _ in people)
            recipe = {"num_frames": n, "people": [
                {"clip": a.id, "mirrored": m, "start": start, "delay": 0, "yaw": 0.0,
                 "xz": [x - float(a.joints[start, 0, 0]), -float(a.joints[start, 0, 2])]}
                for start, m, x in people]}  # fmt: skip
            j = build_scene(recipe, {a.id: a})
            gap = np.linalg.norm(j[1, :, 0, [0, 2]] - j[0, :, 0, [0, 2]], axis=0)
            print(f"{a.id}, {name}: {gap[0]:.2f} m apart at the start, {gap[-1]:.2f} m at "
                  f"the end ({n} frames)")  # fmt: skip


def differ(a: Path, b: Path) -> None:
    sa, sb = (json.loads((c / "scenes.json").read_text()) for c in (a, b))
    for split in sa:
        same = sum(x == y for x, y in zip(sa[split], sb.get(split, []), strict=False))
        print(f"{split}: {len(sa[split]) - same} of {len(sa[split])} scenes differ")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--against", type=Path, default=None)
    args = ap.parse_args()
    side_checks(args.corpus)
    mirrored_fallbacks(args.corpus)
    fallback_gaps()
    if args.against is not None:
        differ(args.against, args.corpus)


if __name__ == "__main__":
    main()
