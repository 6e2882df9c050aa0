"""Single-person FID and R-precision of several models on one split, and nothing else.

    python research/single_protocol.py --corpus out/corpus MODEL [MODEL ...] [--split val]
        [--replications 5] [--length-step 15] [--json FILE]

The single-person table of ``umf eval`` (:func:`umf.eval.report.protocol_section`) for each
model as a contender beside the first, without pairs, groups, accumulation or speed: for
choosing between P-Flow fine-tunes on the val split in minutes, without reading the test
split. Names: the first model's ``format.json`` name, the others' directory names.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", type=Path, nargs="+")
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--replications", type=int, default=5)
    ap.add_argument("--length-step", type=int, default=15)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--evaluator", type=Path, default=None, help="default: the bundled one")
    args = ap.parse_args(argv)

    from umf.data.corpus import Corpus
    from umf.eval.contenders import load_contenders, load_evaluators
    from umf.eval.plan import EvalPlan, default_evaluator_dir
    from umf.eval.report import protocol_section
    from umf.validation import check_device

    device = check_device("auto")
    plan = EvalPlan(replications=args.replications, length_step=args.length_step,
                    split=args.split)  # fmt: skip
    corpus = Corpus.load(args.corpus)
    variants = [(m.name, m) for m in args.models[1:]]
    contenders = load_contenders(args.models[0], variants, device, plan, False)
    evaluators = load_evaluators(args.evaluator or default_evaluator_dir(),
                                 corpus.root / "text-cache", device)  # fmt: skip
    if "single" not in evaluators:
        raise SystemExit("no single-person evaluator")
    notes: list[str] = []
    table = protocol_section(evaluators["single"], corpus, "single", contenders, plan, notes,
                             lambda m: None)  # fmt: skip
    if table is None:
        raise SystemExit("; ".join(notes))
    print(json.dumps(table, indent=1)[:4000])
    if args.json is not None:
        args.json.write_text(json.dumps(table, indent=1) + "\n")


if __name__ == "__main__":
    main()
