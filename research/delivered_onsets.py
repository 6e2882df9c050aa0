"""Does the clean-up move answers in time? Whole-body and upper-body action onsets of the
same generated people, raw and delivered.

    python research/delivered_onsets.py --corpus CORPUS [--model DIR] [--scenes 100]
        [--split val|test] [--relation audience] [--json FILE]

Delivered scenes pass fewer `starts_after` checks than raw ones (20261215's test groups:
0.845 against 0.958; audiences 0.675 against 0.85). The check reads
:func:`umf.data.relations.action_onset` on the whole body relative to the pelvis: the frame
by which a tenth of the person's motion has happened. The fit pins planted feet, and the
legs' motion at rest is then smaller. With a smaller share of motion in the legs, that
frame can move with the arms and head unchanged. This prints, for people 2..N of the groups
of one relation (``--split val``: ``research/group_checks.py``'s, composed from val clips;
``test``: the corpus's test groups, as the protocol generates them), the shift of both
onsets from raw to delivered, how many `starts_after` checks pass raw and delivered, and
how many would pass read on the upper body alone. Nothing is chosen on it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

# the pelvis, spine, neck, head, collars, shoulders, elbows and wrists (SMPL-22)
UPPER = (0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21)


def onsets(joints: np.ndarray) -> tuple[list[int], list[int]]:
    """Each person's (P, T, 22, 3) whole-body and upper-body onsets (frames), as the
    `starts_after` check reads them."""
    from umf.data.relations import ONSET_SMOOTHING, action_onset

    whole = [action_onset(p, smooth=ONSET_SMOOTHING) for p in joints]
    upper = [action_onset(p[:, list(UPPER)], smooth=ONSET_SMOOTHING) for p in joints]
    return whole, upper


def starts_after(onset: list[int], constraints: list[dict]) -> list[bool]:
    """The record's `starts_after` checks read on these onsets."""
    return [onset[c.get("b", 1)] - onset[c.get("a", 0)] >= c.get("min_frames", 8)
            for c in constraints if c["type"] == "starts_after"]  # fmt: skip


def compare(records: list[dict], raw: list[np.ndarray], delivered: list[np.ndarray]) -> dict:
    """Onset shifts (delivered - raw) of people 2..N and `starts_after` pass counts."""
    shift_whole, shift_upper = [], []
    passes = {"raw": 0, "delivered": 0, "raw, upper body": 0, "delivered, upper body": 0}
    count = 0
    for r, a, b in zip(records, raw, delivered, strict=True):
        (wa, ua), (wb, ub) = onsets(a), onsets(b)
        shift_whole += [wb[k] - wa[k] for k in range(1, len(wa))]
        shift_upper += [ub[k] - ua[k] for k in range(1, len(ua))]
        checks = r["constraints"]
        for name, onset in (("raw", wa), ("delivered", wb), ("raw, upper body", ua),
                            ("delivered, upper body", ub)):  # fmt: skip
            passes[name] += sum(starts_after(onset, checks))
        count += len(starts_after(wa, checks))

    def spread(v: list[int]) -> dict:
        a = np.abs(np.asarray(v))
        return {"median_abs": float(np.median(a)), "p90_abs": float(np.percentile(a, 90)),
                "max_abs": int(a.max()), "within_2": float(np.mean(a <= 2))}  # fmt: skip

    return {"people": len(shift_whole), "checks": count, "passing": passes,
            "shift_whole": spread(shift_whole), "shift_upper": spread(shift_upper)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--scenes", type=int, default=100, help="val groups composed (all relations)")
    ap.add_argument("--split", choices=("val", "test"), default="val")
    ap.add_argument("--relation", default="audience")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    from group_checks import val_groups

    from umf.clean_up import delivered_joints
    from umf.data.corpus import Corpus
    from umf.eval.contenders import load_contenders
    from umf.eval.plan import make_plan
    from umf.eval.report import _joints_contacts, generate_records
    from umf.io import atomic_path
    from umf.pipeline import default_model_dir

    corpus = Corpus.load(args.corpus)
    groups = (val_groups(corpus, args.scenes) if args.split == "val"
              else list(corpus.scenes["test_groups"])[: args.scenes])  # fmt: skip
    records = [r for r in groups if r["relation"] == args.relation]
    if not records:
        raise SystemExit(f"error: no {args.relation} among the first {args.scenes} "
                         f"{args.split} groups")  # fmt: skip
    plan = make_plan(quick=False, length_step=15, seed=0)
    (c,) = load_contenders(args.model or default_model_dir(), [], "cpu", plan, progress=False)
    both = generate_records(c, records, plan.seed + 200_000, _joints_contacts)
    out = compare(records, [j for j, _ in both], [delivered_joints(j, k) for j, k in both])
    out.update(model=c.pipe.name, split=args.split, relation=args.relation,
               scenes=len(records))  # fmt: skip
    print(f"{c.pipe.name}: {len(records)} {args.split} {args.relation} scenes, "
          f"{out['people']} people 2..N, {out['checks']} starts_after checks")  # fmt: skip
    for name in ("whole", "upper"):
        s = out[f"shift_{name}"]
        print(f"  {name}-body onset, delivered - raw: median |shift| {s['median_abs']:.0f}, "
              f"p90 {s['p90_abs']:.0f}, max {s['max_abs']} frames; within 2 frames "
              f"{s['within_2']:.0%}")  # fmt: skip
    print("  starts_after passing: " + ", ".join(f"{k} {v}" for k, v in out["passing"].items()))
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
