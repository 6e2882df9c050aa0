"""Can a flow tell the own prompts apart? Their own-prompt tokens, and what person 2 does
for each with a real person 1 (the evidence behind ``denoiser.person_head``).

    python research/own_tokens.py [--model DIR] [--corpus DIR] [--seeds 4]

1. tokens: for each flow, the cosine similarity of the own-prompt tokens
   (``net.person_token``) of five gesture prompts, each centred on the mean over ten
   prompts: two prompts the flow cannot tell apart have a cosine near 1;
2. probe (``--corpus``): person 1 is the first ``stand_facing`` test scene's real person 1
   ("Two people stand facing each other.", seeds 0..N-1, raw joints); person 2 is told each
   prompt in turn; medians of person 2's lower wrist above the head, right wrist above the
   head and head drop (m). Without an own prompt is the baseline.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

PROMPTS = ["A person raises both hands.", "A person raises the right hand.",
           "A person raises the left hand.", "A person waves with the right hand.",
           "A person waves with both hands.", "Someone bows politely.", "A person kicks.",
           "A person punches.", "A person calls out to someone.",
           "A person points the way."]  # fmt: skip
SHOWN = 5  # the gestures' rows and columns of the cosine table
STATS = ("both_wrists_above_head", "right_wrist_above_head", "head_drop")


def tokens(pipe) -> None:
    import torch

    text = pipe.text_encoder.encode(PROMPTS).to(pipe.device)
    for name, flow in (("P-Flow", pipe.pflow), ("S-Flow", pipe.sflow)):
        with torch.no_grad():
            own = flow.net.person_token(text, len(PROMPTS))
        v = torch.nn.functional.normalize(own - own.mean(0), dim=-1)
        cos = (v @ v.T).cpu().numpy()[:SHOWN, :SHOWN]
        print(f"{name}: centred cosine of the own-prompt tokens")
        for p, row in zip(PROMPTS[:SHOWN], cos, strict=True):
            print(f"  {p:34s} " + " ".join(f"{c:+.2f}" for c in row))


def probe(pipe, corpus_dir: Path, seeds: int) -> None:
    from umf.data.corpus import Corpus
    from umf.eval.motion_stats import motion_statistics

    corpus = Corpus.load(corpus_dir)
    scenes = json.loads((corpus_dir / "scenes.json").read_text())["test"]
    recipe = next(r for r in scenes if r["relation"] == "stand_facing")
    joints = corpus.scene_joints(recipe)
    actor = joints[0, : min(121, joints.shape[1])]
    print(f"person 1: a real {recipe['people'][0]['content']!r} ({recipe['id']}), seeds "
          f"0-{seeds - 1}; person 2's medians (m): " + ", ".join(STATS))  # fmt: skip
    for own in [None, *PROMPTS]:
        rows = [motion_statistics(np.asarray(pipe("Two people stand facing each other.",
                                                  num_people=2, seed=s, actor=actor,
                                                  person_prompts=[None, own], fit=False,
                                                  separate=False)[0].joints[1]))
                for s in range(seeds)]  # fmt: skip
        med = [float(np.median([r[k] for r in rows])) for k in STATS]
        print(f"  {own!s:34s} " + " ".join(f"{m:+.2f}" for m in med))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    print(f"model {pipe.name}")
    tokens(pipe)
    if args.corpus is not None:
        probe(pipe, args.corpus, args.seeds)


if __name__ == "__main__":
    main()
