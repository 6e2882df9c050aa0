"""Which group checks fail, and where people 3..N stand: the groups part of the reactions
issue, on a held-out set that is not the test set.

    python research/group_checks.py --corpus CORPUS [--model DIR] [--scenes 100]
        [--split val] [--pairs [--relation NAME ...]] [--seed S] [--set key=value ...]
        [--context all|leader|previous|previous-frame|all-previous-frame] [--json FILE]

The protocol's groups of 3-6 are the zero-shot *test* set; a sampling setting chosen on them
would flatter the report. ``--split val`` (default) composes groups the same way
(:func:`umf.data.composer.compose_corpus`, the corpus's relations and sizes) from the
validation clips, which no model trained on; ``--split test`` scores the corpus's own
``test_groups``. Scenes are generated as the protocol does (``umf.eval``: first caption, own
length, raw ``fit=False, separate=False``) and scored raw and delivered
(:func:`umf.pipeline.delivered_joints`): scenes passing every check, per relation, per check
kind, in any order of the people a group's caption does not tell apart
(:func:`umf.eval.relations.any_order_checks`), and how each person k >= 3 relates to those
before it (closest joints to anyone earlier). ``--pairs`` scores the split's two-person
scenes instead (what ``--set pair_steps=N`` was chosen on). ``--set`` changes an ``sflow``
config value for the run.

``--context`` tries other contexts for person k >= 3 than everybody before them (``all``,
the method's): person 1 alone (``leader``), person k - 1 alone (``previous``), or person k - 1
(``previous-frame``) or everybody (``all-previous-frame``) re-encoded in person k - 1's own
frame, where person k is generated and from where it is moved back (decoded, moved and
encoded again: person k passes through the VAE once more than in the pipeline).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

VAL_SEED = 1_017  # the val groups' composition seed (test groups use the corpus seed + 7)


def val_groups(corpus, count: int) -> list[dict]:
    """``count`` groups of 3-6 composed from the corpus's validation clips."""
    from umf.data.composer import compose_corpus
    from umf.data.corpus import _actor

    actors = [_actor(c) for c in corpus.clips if c.split == "val" and c.num_people == 1]
    sizes = tuple(corpus.manifest.get("config", {}).get("group_sizes", (3, 4, 5, 6)))
    return compose_corpus(actors, count, sizes, seed=VAL_SEED)


def closest_to_earlier(joints: np.ndarray) -> list[float]:
    """For each person k >= 2 (0-based), the closest any of their joints comes to a joint of
    someone generated before them (m)."""
    from umf.data.relations import closest_joints

    return [min(closest_joints(joints[k], joints[j])[0] for j in range(k))
            for k in range(2, joints.shape[0])]  # fmt: skip


def patch_context(mode: str) -> None:
    """Replace ``umf.pipeline.sample_added`` for person k >= 3 (module notes)."""
    import torch

    import umf.pipeline as pipeline
    from umf.representation import leader_frame, transform_features

    sample_added = pipeline.sample_added

    def patched(pipe, prev, mask, text, uncond, frames, **kw):
        b, n = prev.shape[:2]
        if n == 1 or mode == "all":
            return sample_added(pipe, prev, mask, text, uncond, frames, **kw)
        if mode in ("leader", "previous"):
            keep = slice(0, 1) if mode == "leader" else slice(n - 1, n)
            return sample_added(pipe, prev[:, keep], mask[:, keep], text, uncond, frames, **kw)
        decoded = torch.stack(
            [pipe.decode(prev[:, j], frames, reaction=j > 0) for j in range(n)], dim=1
        )  # person 1 fused as person 1
        frame = [leader_frame(decoded[i, -1]) for i in range(b)]
        people = range(n - 1, n) if mode == "previous-frame" else range(n)
        moved = torch.stack([torch.stack([transform_features(decoded[i, j], frame[i])
                                          for j in people]) for i in range(b)])  # fmt: skip
        context = pipe._encode(moved.flatten(0, 1)).reshape(b, len(people), *prev.shape[2:])
        ones = torch.ones(context.shape[:2], dtype=torch.bool, device=context.device)
        w, nfe = sample_added(pipe, context, ones, text, uncond, frames, **kw)
        there = pipe.decode(w, frames, reaction=True)
        back = [transform_features(there[i], frame[i], inverse=True) for i in range(b)]
        return pipe._encode(torch.stack(back)), nfe

    pipeline.sample_added = patched


def score(records: list[dict], joints: list[np.ndarray]) -> dict:
    from umf.data.relations import check_record
    from umf.eval.relations import any_order_checks

    scenes = defaultdict(list)
    loose = defaultdict(list)
    kinds = defaultdict(list)
    by_rel_kind = defaultdict(list)
    for r, j in zip(records, joints, strict=True):
        res = check_record(j, r)
        ok = all(c.passed for c in res)
        scenes[r["relation"]].append(ok)
        scenes["all"].append(ok)
        free = all(c.passed for c in any_order_checks(r, j))
        loose[r["relation"]].append(free)
        loose["all"].append(free)
        for c in res:
            kinds[c.type].append(c.passed)
            by_rel_kind[f"{r['relation']}/{c.type}"].append(c.passed)
    mean = lambda v: round(float(np.mean(v)), 3)  # noqa: E731
    gaps = [g for j in joints for g in closest_to_earlier(j)]
    return {
        "failing": len(scenes["all"]) - sum(scenes["all"]),  # scenes failing a check
        "scenes": {k: mean(v) for k, v in sorted(scenes.items())},
        "any_order": {k: mean(v) for k, v in sorted(loose.items())},
        "kinds": {k: mean(v) for k, v in sorted(kinds.items())},
        "relation_kinds": {k: mean(v) for k, v in sorted(by_rel_kind.items())},
        "closest_m": [round(float(np.median(gaps)), 3) if gaps else None],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--split", choices=("val", "test"), default="val")
    ap.add_argument(
        "--pairs", action="store_true", help="score the split's two-person scenes instead of groups"
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an sflow config value for this run (e.g. pair_steps=10)",
    )
    ap.add_argument(
        "--relation",
        action="append",
        default=[],
        help="with --pairs: only the scenes of this relation among the first --scenes "
        "(repeatable; e.g. walk_side_by_side)",
    )
    ap.add_argument("--seed", type=int, default=0, help="the evaluation plan's seed")
    ap.add_argument(
        "--context",
        default="all",
        choices=("all", "leader", "previous", "previous-frame", "all-previous-frame"),
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    from umf.data.corpus import Corpus
    from umf.eval.contenders import load_contenders
    from umf.eval.plan import make_plan
    from umf.eval.report import _joints_contacts, generate_records
    from umf.pipeline import default_model_dir, delivered_joints

    patch_context(args.context)
    corpus = Corpus.load(args.corpus)
    if args.pairs:
        records = list(corpus.scenes[args.split])[: args.scenes]
        if args.relation:
            records = [r for r in records if r.get("relation") in args.relation]
    elif args.split == "val":
        records = val_groups(corpus, args.scenes)
    else:
        records = list(corpus.scenes["test_groups"])[: args.scenes]
    plan = make_plan(quick=False, length_step=15, seed=args.seed)
    model = args.model or default_model_dir()
    (c,) = load_contenders(model, [], "cpu", plan, progress=False)
    for item in args.set:
        key, value = item.split("=", 1)
        if not hasattr(c.pipe.config.sflow, key):
            raise SystemExit(f"error: --set {item}: sflow has no option {key!r}")
        setattr(c.pipe.config.sflow, key, json.loads(value))
    both = generate_records(c, records, plan.seed + 200_000, _joints_contacts)
    raw = [j for j, _ in both]
    delivered = [delivered_joints(j, k) for j, k in both]
    out = {"model": c.pipe.name, "split": args.split, "scenes": len(records), "set": args.set,
           "context": args.context, "raw": score(records, raw),
           "delivered": score(records, delivered)}  # fmt: skip
    for name in ("raw", "delivered"):
        s = out[name]
        print(f"== {name}: {s['failing']} of {len(records)} scenes fail a check")
        print(
            f"== {name}: scenes passing {s['scenes']['all']}, closest to earlier "
            f"(median) {s['closest_m'][0]} m"
        )
        print("  relations: " + ", ".join(f"{k} {v}" for k, v in s["scenes"].items()))
        print(
            "  in any order (umf.eval.relations.any_order_checks): "
            + ", ".join(f"{k} {v}" for k, v in s["any_order"].items())
        )
        print("  kinds: " + ", ".join(f"{k} {v}" for k, v in s["kinds"].items()))
        for k, v in s["relation_kinds"].items():
            if v < 1.0:
                print(f"    {k}: {v}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
