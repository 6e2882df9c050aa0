"""Do answers wait? Person 2's action onset after person 1's, for answering prompts.

For each prompt and duration, seeds 0..N-1, raw output (``fit=False, separate=False``, as
the protocol scores it): how many seeds have person 2 start at least 8 frames after person 1
(the checks' reading, :func:`umf.data.relations.action_onset` averaged over
``ONSET_SMOOTHING``), and the median gap, with the model's ``sflow.warm_timing`` and with
it off. Then where the bank finds each prompt's answers (the stored length the scene asks,
the length holding the prompt's nearest caption, that caption's median wait and number of
reactions), how full the longest stored length is, and, with ``--corpus``, how far apart the
onsets of the train split's real takes are (people acting together: not stored as waits).

    python research/answer_waits.py [MODEL_DIR] [--seeds 12] [--corpus CORPUS]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from umf.coverage import embed
from umf.data.relations import ONSET_SMOOTHING, action_onset
from umf.pipeline import UMFPipeline, default_model_dir

PROMPTS = ("One person bows and the other bows back.", "Two people face each other and fight.",
           "One person calls out and the other responds.")  # fmt: skip


def gaps(pipe: UMFPipeline, prompt: str, seconds: float, seeds: int) -> list[int]:
    out = []
    for seed in range(seeds):
        (scene,) = pipe(prompt, num_people=2, seconds=seconds, seed=seed, fit=False,
                        separate=False)  # fmt: skip
        a, b = (action_onset(np.asarray(j), smooth=ONSET_SMOOTHING) for j in scene.joints)
        out.append(b - a)
    return out


def bank_table(pipe: UMFPipeline) -> None:
    bank = pipe.reactions
    prompts = embed(pipe.text_encoder, list(PROMPTS))
    for seconds in (4.0, 10.0):
        frames = round(seconds * pipe.config.fps)
        for prompt, at in zip(PROMPTS, bank.caption_length(frames, prompts), strict=True):
            found = bank.caption_waits(at, embed(pipe.text_encoder, [prompt]))
            wait, count = ("-", 0) if found is None else (f"{float(found[0][0]):.0f}",
                                                          int(found[1][0]))  # fmt: skip
            print(
                f"  bank, {prompt:46s} {seconds:4.0f} s: asks {bank.bucket(frames)} frames, "
                f"its caption at {at}: {count} reactions, median wait {wait}"
            )
    longest = max(bank.lengths())
    distinct = len(torch.unique(bank.texts[longest], dim=0)) if longest in bank.texts else 0
    print(
        f"  bank, longest length {longest}: {len(bank.latents[longest])} reactions of "
        f"{distinct} captions"
    )


def take_gaps(pipe: UMFPipeline, corpus_dir: str) -> None:
    from umf.data.corpus import Corpus
    from umf.train.datasets import SceneDataset
    from umf.warm_start import onsets

    ds = SceneDataset(Corpus.load(corpus_dir), "train", None, min_frames=30, max_frames=30)
    for i, (kind, item, _) in enumerate(ds.items):
        if kind == "clip":
            start = onsets(ds.whole(i))
            print(
                f"  real take {item.id}: person 2 starts {start[1] - start[0]:+d} frames "
                f"after person 1 ({item.meta.get('content', '')})"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--corpus", default=None, help="also the train split's real takes")
    args = ap.parse_args()
    pipe = UMFPipeline.from_pretrained(args.model or default_model_dir())
    own = pipe.config.sflow.warm_timing
    print(f"model {pipe.name}; seeds 0-{args.seeds - 1}; waits >= 8 frames, median gap")
    for prompt in PROMPTS:
        for seconds in (4.0, 10.0):
            cells = []
            for timing in (own, 0.0):
                pipe.config.sflow.warm_timing = timing
                g = gaps(pipe, prompt, seconds, args.seeds)
                cells.append(f"warm_timing {timing:g}: {sum(x >= 8 for x in g):2d} of "
                             f"{len(g)}, median {np.median(g):+.0f}")  # fmt: skip
            pipe.config.sflow.warm_timing = own
            print(f"  {prompt:48s} {seconds:4.0f} s | " + " | ".join(cells))
    bank_table(pipe)
    if args.corpus:
        take_gaps(pipe, args.corpus)


if __name__ == "__main__":
    main()
