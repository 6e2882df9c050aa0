"""Where raw groups touch, and what ``sflow.warm_clear`` changes: the counts behind the
release page's "Why" and "Other checks".

    python results/umf-small-bandai-20261215/tried/raw_contacts.py CORPUS [--scenes 100]
        [--set key=value ...] [--no-val] [--speed]

1. The val groups (``research/group_checks.py``'s 100, raw as the protocol generates them):
   every two people whose joints come within 0.25 m, by relation, whether person 1 is one of
   them, and the first frame they do; for people k >= 3, how often the S-Flow's first pass
   touches someone before them, and how far the second pass starts from its proposal.
2. The bundled test's scenes (a circle of five, a gathering of five, a file of four; seeds
   0-3, raw): the closest two people come.
3. Circles of 8, 12 and 16 (seed 0, raw): the same.
4. With ``--speed``: seconds per delivered group scene (the 9 scenes of 4-5 people of item
   2's prompts, seeds 0-2), the bundled model with ``sflow.warm_clear`` 0 and 0.55 in turn,
   twice, in one process after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))

from group_checks import val_groups

PROMPTS = (("Five people stand in a circle and bow.", 5),
           ("A person calls and four people walk over to them.", 5),
           ("Four people walk in single file.", 4))  # fmt: skip


def touching_pairs(joints: np.ndarray) -> list[tuple[int, int, int]]:
    """(a, b, first frame) for every two people (0-based) whose joints come within the
    checks' contact distance."""
    from umf.data.relations import CONTACT_DISTANCE

    n, out = joints.shape[0], []
    for a in range(n):
        for b in range(a + 1, n):
            d = np.linalg.norm(joints[a][:, :, None] - joints[b][:, None], axis=-1).min((1, 2))
            frames = np.flatnonzero(d < CONTACT_DISTANCE)
            if len(frames):
                out.append((a, b, int(frames[0])))
    return out


def val_contacts(corpus, pipe, scenes: int) -> None:
    import torch

    import umf.models.sflow
    from umf.eval.plan import make_plan
    from umf.eval.report import _joints_contacts, generate_records
    from umf.representation import features_to_joints, floor_start
    from umf.warm_start import touches

    records = val_groups(corpus, scenes)
    first_touch, drift = [], []
    real = umf.models.sflow.SFlow.sample

    def spy(self, prev, *args, warm=None, **kwargs):
        w, nfe = real(self, prev, *args, warm=warm, **kwargs)
        if prev.shape[1] > 1:  # person k >= 3: decoded at a common length, as the bank's
            frames = 120
            b, m = prev.shape[:2]
            there = spy.pipe.decode(prev.flatten(0, 1), frames, reaction=True)
            bodies = features_to_joints(there).reshape(b, m, frames, 22, 3)
            mine = spy.pipe.decode(w, frames, reaction=True)
            if warm is None:
                first_touch.extend(touches(mine, bodies, 0.25).tolist())
            else:
                proposed = spy.pipe.decode(warm, frames, reaction=True)
                gap = (floor_start(proposed) - floor_start(mine)).norm(dim=-1)
                drift.extend(gap.tolist())
        return w, nfe

    spy.pipe = pipe.pipe
    umf.models.sflow.SFlow.sample = spy
    try:
        plan = make_plan(quick=False, length_step=15, seed=0)
        with torch.no_grad():
            both = generate_records(pipe, records, plan.seed + 200_000, _joints_contacts)
    finally:
        umf.models.sflow.SFlow.sample = real
    pairs, by = [], Counter()
    for r, (j, _) in zip(records, both, strict=True):
        for a, _, frame in touching_pairs(np.asarray(j)):
            pairs.append(frame)
            by[r["relation"], "with person 1" if a == 0 else "people 2..N"] += 1
    frames = np.asarray(pairs)
    print(f"val groups ({len(records)}), raw: {len(pairs)} touching pairs")
    for (relation, who), count in sorted(by.items()):
        print(f"  {relation}, {who}: {count}")
    if len(frames):
        print(f"  first frame touching: at frame 0 {np.mean(frames == 0):.0%}, median "
              f"{np.median(frames):.0f}")  # fmt: skip
    if first_touch:
        print(f"  people k >= 3 whose first pass touches someone before them: "
              f"{np.mean(first_touch):.0%} of {len(first_touch)}")  # fmt: skip
    if drift:
        print(f"  second pass's start from its proposal (m): median {np.median(drift):.3f}, "
              f"p90 {np.percentile(drift, 90):.3f}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--no-val", action="store_true")
    ap.add_argument("--speed", action="store_true")
    args = ap.parse_args()

    from umf.data.corpus import Corpus
    from umf.data.relations import min_interperson_distance
    from umf.eval.contenders import load_contenders
    from umf.eval.plan import make_plan
    from umf.pipeline import default_model_dir

    plan = make_plan(quick=False, length_step=15, seed=0)
    (c,) = load_contenders(default_model_dir(), [], "cpu", plan, progress=False)
    for item in args.set:
        key, value = item.split("=", 1)
        setattr(c.pipe.config.sflow, key, json.loads(value))
    print(f"{c.pipe.name} {' '.join(args.set)}")
    if not args.no_val:
        val_contacts(Corpus.load(args.corpus), c, args.scenes)
    pipe = c.pipe
    apart = []
    for prompt, n in PROMPTS:
        gaps = []
        for seed in range(4):
            (s,) = pipe(prompt, num_people=n, seconds=4.0, seed=seed, fit=False, separate=False)
            gaps.append(min_interperson_distance(np.asarray(s.joints))[0])
        apart += [g >= 0.25 for g in gaps]
        print(f"{prompt} seeds 0-3, raw, closest two people (m): "
              + ", ".join(f"{g:.3f}" for g in gaps))  # fmt: skip
    print(f"  scenes keeping 0.25 m: {sum(apart)} of {len(apart)}")
    for n in (8, 12, 16):
        (s,) = pipe("People stand in a circle and bow.", num_people=n, seconds=4.0, seed=0,
                    fit=False, separate=False)  # fmt: skip
        gap = min_interperson_distance(np.asarray(s.joints))[0]
        print(f"a circle of {n}, seed 0, raw: closest two people {gap:.3f} m")
    if args.speed:
        from umf.pipeline import UMFPipeline

        bundled = UMFPipeline.from_pretrained()
        bundled(PROMPTS[0][0], num_people=5, seconds=4.0, seed=0)  # warm-up
        for clear in (0.0, 0.55, 0.0, 0.55):
            bundled.config.sflow.warm_clear = clear
            start = time.perf_counter()
            for prompt, n in PROMPTS:
                for seed in range(3):
                    bundled(prompt, num_people=n, seconds=4.0, seed=seed)
            took = (time.perf_counter() - start) / 9
            print(f"seconds per delivered group scene (9), warm_clear {clear}: {took:.3f}")


if __name__ == "__main__":
    main()
