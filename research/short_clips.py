"""Which short training clips ``train_*.hold_rest``, ``repeat_gait`` and ``settle`` extend.

A clip shorter than the shortest crop (``--min-frames`` feature frames) is held in its last
pose (ends at rest), has its last cycle repeated (ends in a steady, straight gait), is eased
to a stop and held (ends slowly; only with ``--settle``, as ``train_*.settle``) or is
served as it is (``umf.data.extension.extension_period``, the dataset's own choice). Prints
one row per content label, then the seam and turn of the repeated cycles
(``umf.data.extension.last_cycle``), the median length of each label's short clips, and
for every short clip eased or served as it is the speeds that kept it from being held
(``umf.data.extension.end_speeds``: pelvis, left ankle and toe, right ankle and toe).

    python research/short_clips.py [--corpus out/corpus] [--split train] [--min-frames 140]
        [--settle]
"""

from __future__ import annotations

import argparse
import math
from collections import Counter, defaultdict

import numpy as np

from umf.data.extension import (
    REST_SPEED,
    SETTLE,
    SETTLE_SPEED,
    end_speeds,
    extension_period,
    last_cycle,
)

KINDS = ("held", "cycle repeated", "eased to a stop", "as is")
Unrested = tuple[str, int, str, np.ndarray]  # clip id, frames, kind, end speeds


def kind(period: int | None) -> str:
    """The :data:`KINDS` name of an extension period."""
    if period is None:
        return KINDS[3]
    return KINDS[0] if period == 0 else KINDS[2] if period == SETTLE else KINDS[1]


def classify(
    clips, min_frames: int, settle: bool = False
) -> tuple[dict[str, Counter], list[tuple[float, float]], dict, list[Unrested]]:
    """Per label, how its short people are extended; (seam m, turn rad) of every repeated
    cycle; per label, the lengths (frames) of its short people; (clip id, frames, kind, end
    speeds) of every short person eased to a stop or served as it is."""
    kinds: dict[str, Counter] = defaultdict(Counter)
    seams: list[tuple[float, float]] = []
    lengths: dict[str, list[int]] = defaultdict(list)
    as_is: list[Unrested] = []
    for clip in clips:
        label = str(clip.meta.get("content", "?"))
        for joints in clip.joints:
            if len(joints) - 1 >= min_frames:
                continue
            period = extension_period(joints, min_frames, True, True, settle)
            kinds[label][kind(period)] += 1
            lengths[label].append(len(joints))
            if period is None or period == SETTLE:
                as_is.append((clip.id, len(joints), kind(period), end_speeds(joints)))
            if period and period > 0:
                _, seam, turn, _ = last_cycle(joints)
                seams.append((seam, turn))
    return kinds, seams, lengths, as_is


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--split", default="train")
    ap.add_argument("--min-frames", type=int, default=140)
    ap.add_argument("--settle", action="store_true", help="as train_*.settle: ease slow ends")
    args = ap.parse_args()
    from umf.data.corpus import Corpus

    clips = Corpus.load(args.corpus).split_clips(args.split)
    kinds, seams, lengths, as_is = classify(clips, args.min_frames, args.settle)
    people = sum(len(c.joints) for c in clips)
    total = Counter()
    for c in kinds.values():
        total.update(c)
    print(
        f"{args.split}: {people} people, {sum(total.values())} shorter than "
        f"{args.min_frames + 1} frames: " + ", ".join(f"{total[k]} {k}" for k in KINDS)
    )
    print("\n| label | short | " + " | ".join(KINDS) + " | median length (s) |")
    print("|---|---:|" + "---:|" * (len(KINDS) + 1))
    for label, c in sorted(kinds.items(), key=lambda kv: -sum(kv[1].values())):
        med = np.median(lengths[label]) / 30
        print(
            f"| {label} | {sum(c.values())} | "
            + " | ".join(str(c[k]) for k in KINDS)
            + f" | {med:.1f} |"
        )
    if seams:
        s, t = np.array(seams).T
        print(
            f"\nrepeated cycles: seam median {np.median(s) * 100:.1f} cm, max "
            f"{s.max() * 100:.1f} cm; turn median {math.degrees(np.median(t)):.1f}, max "
            f"{math.degrees(t.max()):.1f} degrees"
        )
    if as_is:
        print(f"\nnot at rest (rest needs every speed under {REST_SPEED} m/s; easing to a stop, "
              f"under {SETTLE_SPEED} m/s):")  # fmt: skip
        print("| clip | frames | served | pelvis | l ankle | l toe | r ankle | r toe (m/s) |")
        print("|---|---:|---|---:|---:|---:|---:|---:|")
        for cid, frames, how, v in sorted(as_is, key=lambda row: row[:3]):
            print(f"| {cid} | {frames} | {how} | " + " | ".join(f"{x:.2f}" for x in v) + " |")


if __name__ == "__main__":
    main()
