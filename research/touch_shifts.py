"""How far the clean-up's separation moves real couples: the "touching" rule checked on the data.

    python research/touch_shifts.py [--corpus out/corpus] [--model DIR] [--seconds 4]

Every real multi-person take of the corpus whose people touch, cut into crops of
``--seconds`` every half of that: person 2's floor shift from the separation as the
pipeline applies it to a prompt worded like the take's caption (the model's vocabulary
``contact``), against the rule before 20261213, which held the closest takes' 5th
percentiles (joints, plus the fit's margin; pelvises) at every frame. A rule that lets real
partners stay where they are shifts these crops by nothing, or by the centimetre the
TOUCH_FLOOR asks of the rare frame where two joints come within 2 cm. Last, how much the
real couples' bodies overlap in these crops (every crop, holding hands or not): the
reference for a generated couple's overlap.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def crops(joints: np.ndarray, frames: int):
    """Crops (P, frames, 22, 3) every frames // 2."""
    for s in range(0, joints.shape[1] - frames + 1, max(1, frames // 2)):
        yield joints[:, s : s + frames]


def row(name: str, split: str, now: list[float], before: list[float]) -> str:
    return (f"{name:28s} {split:5s} {len(now):5d}  {np.median(now):8.1f} / {max(now):5.1f}"
            f"{'':11s}{np.median(before):8.1f} / {max(before):5.1f}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, default=Path("out/corpus"))
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seconds", type=float, default=4.0)
    args = ap.parse_args()

    from umf.coverage import Vocabulary
    from umf.data.corpus import Corpus
    from umf.data.relations import pair_closeness
    from umf.eval.physics import capsule_penetration
    from umf.pipeline import default_model_dir
    from umf.separation import FIT_MARGIN, MIN_DISTANCE, separate_people, touching_distances

    corpus = Corpus.load(args.corpus)
    vocab = Vocabulary.load(args.model or default_model_dir())
    print(f"{'take':28s} {'split':5s} crops  shift now: median / max (cm)   earlier rule")
    now_all, before_all = [], []
    overlap: list[tuple[float, float]] = []  # every crop's mean depth (cm), share over 1 cm
    for clip in corpus.clips:
        if clip.num_people < 2 or not any(c in vocab.contact for c in clip.captions):
            continue
        contact = next(vocab.contact[c] for c in clip.captions if c in vocab.contact)
        now_kw = touching_distances(contact)
        before_kw = {"min_distance": min(MIN_DISTANCE, contact["pelvis_m"]), "smallest": True,
                     "contact_distance": contact["closest_m"] + FIT_MARGIN}  # fmt: skip
        now, before = [], []
        for crop in crops(clip.joints[:2].astype(np.float64), round(args.seconds * clip.fps) + 1):
            depth = capsule_penetration(crop[0], crop[1])
            overlap.append((float(depth.mean() * 100), float((depth > 0.01).mean())))
            if pair_closeness(crop)["hands_near"] < 0.25:
                continue  # a stretch where this couple lets go: no touching to keep
            now.append(np.linalg.norm(separate_people(crop, **now_kw)[1][1]) * 100)
            before.append(np.linalg.norm(separate_people(crop, **before_kw)[1][1]) * 100)
        if not now:
            continue
        now_all += now
        before_all += before
        print(row(clip.id[-28:], clip.split, now, before))
    print(row("all", "", now_all, before_all))
    print(f"crops moved more than 2 cm: now {sum(x > 2 for x in now_all)}, earlier rule "
          f"{sum(x > 2 for x in before_all)} of {len(now_all)}")  # fmt: skip
    depth, share = np.array(overlap).T

    def spread(x: np.ndarray) -> str:
        return " / ".join(f"{v:.2f}" for v in (np.percentile(x, 50), np.percentile(x, 95), x.max()))

    print(
        f"the bodies' overlap over all {len(depth)} crops (umf.eval.physics capsules), p50 / "
        f"p95 / max: mean depth {spread(depth)} cm; frames over 1 cm {spread(share)}"
    )


if __name__ == "__main__":
    main()
