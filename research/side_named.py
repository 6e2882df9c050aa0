"""Does the second person keep the side a prompt names? The "stand on the side they are
asked" part of the reactions issue, measured on a model.

    python research/side_named.py [--model DIR] [--seeds 8] [--json FILE]

For side-by-side walks and runs of two people, each prompt asked with "left" and with
"right", seeds 0..N-1, 4 s: the pair checks' own "side" test (person 2 more than 0.2 m to
that side of person 1, in person 1's facing frame at the first frame,
``umf.data.relations.check``), raw (``fit=False, separate=False``, what evaluation scores)
and delivered (the default call). Prompts: the composer's own first wording (trained), and a
paraphrase it never wrote (held out). A prompt that names no side is counted too: which side
the model picks by itself (no target).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

NAMED = {
    "walk, trained wording": "Two people walk side by side, the second person on the first "
    "one's {side}.",
    "run, trained wording": "Two people run side by side, the second person on the first "
    "one's {side}.",
    "walk, held-out paraphrase": "Two friends walk together, the second one on the {side} of "
    "the first.",
}
UNNAMED = "Two people walk side by side."


def lateral(joints: np.ndarray) -> float:
    """Metres person 2 stands to person 1's left (negative: right) at the first frame."""
    from umf.data.relations import lateral_offset

    return float(lateral_offset(joints, 0, 1, 0)[0])


def passes(joints: np.ndarray, side: str) -> bool:
    """The pair checks' own "side" test of person 2 against person 1 (first frame)."""
    from umf.data.relations import check

    return check(joints, {"type": "side", "a": 0, "b": 1, "side": side}).passed


def measure(model: Path | None, seeds: int) -> dict:
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    out: dict = {"model": pipe.name, "seeds": seeds, "named": {}, "unnamed": {}}
    for kind, template in NAMED.items():
        row = {}
        for side in ("left", "right"):
            prompt = template.format(side=side)
            raw = pipe([prompt] * seeds, num_people=2, seed=0, sample_indices=range(seeds),
                       fit=False, separate=False)  # fmt: skip
            delivered = pipe([prompt] * seeds, num_people=2, seed=0, sample_indices=range(seeds))
            for name, scenes in (("raw", raw), ("delivered", delivered)):
                joints = [s.joints for s in scenes]
                row[f"{side} {name}"] = {
                    "left_m": [round(lateral(j), 3) for j in joints],
                    "passed": sum(passes(j, side) for j in joints),
                }
        out["named"][kind] = row
    raw = pipe([UNNAMED] * seeds, num_people=2, seed=0, sample_indices=range(seeds), fit=False,
               separate=False)  # fmt: skip
    out["unnamed"] = {"prompt": UNNAMED, "left_m": [round(lateral(s.joints), 3) for s in raw],
                      "left": sum(passes(s.joints, "left") for s in raw),
                      "right": sum(passes(s.joints, "right") for s in raw)}  # fmt: skip
    return out


def report(m: dict) -> str:
    n = m["seeds"]
    lines = [f"model {m['model']}; {n} seeds, 4 s; passed = person 2 > 0.2 m on the named side"]
    total = {"raw": [0, 0], "delivered": [0, 0]}
    for kind, row in m["named"].items():
        cells = []
        for key, v in row.items():
            cells.append(f"{key} {v['passed']}/{n}")
            stage = key.split()[1]
            total[stage][0] += v["passed"]
            total[stage][1] += n
        lines.append(f"  {kind:28s} " + ", ".join(cells))
    for stage, (ok, all_) in total.items():
        lines.append(f"  all named, {stage}: {ok}/{all_} = {ok / all_:.2f}")
    u = m["unnamed"]
    lines.append(f"  no side named ({u['prompt']!r}), raw: left {u['left']}, right {u['right']}, "
                 f"neither {n - u['left'] - u['right']}")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    m = measure(args.model, args.seeds)
    print(report(m))
    if args.json:
        from umf.io import write_json_atomic

        write_json_atomic(args.json, m)


if __name__ == "__main__":
    main()
