"""Gatherings composed from the *train* clips, scored raw and delivered: where the
`approach` checks that the release's first test read lost were looked into.

    python results/umf-small-bandai-20261215/tried/train_gathers.py CORPUS [--scenes 30]
        [--model DIR] [--set key=value ...]

The val clips compose no gathering (none of their walks is long enough to walk up to the
caller), and the test split had been read once already, so the cause was looked for here:
the people are real training clips, but no model ever trained on a group.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))

from group_checks import VAL_SEED, score


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()

    from umf.data.composer import compose_corpus
    from umf.data.corpus import Corpus, _actor
    from umf.eval.contenders import load_contenders
    from umf.eval.plan import make_plan
    from umf.eval.report import _joints_contacts, generate_records
    from umf.pipeline import default_model_dir, delivered_joints

    corpus = Corpus.load(args.corpus)
    actors = [_actor(c) for c in corpus.clips if c.split == "train" and c.num_people == 1]
    composed = compose_corpus(actors, 400, (3, 4, 5, 6), seed=VAL_SEED)
    records = [r for r in composed if r["relation"] == "gather"][: args.scenes]
    plan = make_plan(quick=False, length_step=15, seed=0)
    (c,) = load_contenders(args.model or default_model_dir(), [], "cpu", plan, progress=False)
    for item in args.set:
        key, value = item.split("=", 1)
        setattr(c.pipe.config.sflow, key, json.loads(value))
    both = generate_records(c, records, plan.seed + 200_000, _joints_contacts)
    print(f"{c.pipe.name} {' '.join(args.set)}: {len(records)} gatherings of train clips")
    for name, joints in (("raw", [j for j, _ in both]),
                         ("delivered", [delivered_joints(j, k) for j, k in both])):  # fmt: skip
        s = score(records, joints)
        kinds = ", ".join(f"{k} {v}" for k, v in s["kinds"].items())
        print(f"  {name}: scenes passing {s['scenes']['all']}; {kinds}")


if __name__ == "__main__":
    main()
