"""Can each flow tell the scene prompts apart that ask for a side or for a delay? The
text tokens of the pair captions whose checks fail most (side, starts_after).

    python research/scene_tokens.py [--model DIR]

For the frozen text encoder's pooled embedding, the P-Flow's and the S-Flow's text tokens
(``net.encode_text``: the text head's one conditioning vector), the cosine similarity of
prompt pairs that differ only in what a check reads, each vector centred on the mean over
every prompt here (the part all scene prompts share taken out): a side named left against
right, a named side against none, a bow answered later against bows exchanged together. A
pair the flow cannot tell apart has a centred cosine near 1; different scenes (a walk
against a bow) are the scale.
"""

from __future__ import annotations

import argparse
from pathlib import Path

PROMPTS = {
    "walk L": "two people walk side by side, the second person on the first one's left.",
    "walk R": "two people walk side by side, the second person on the first one's right.",
    "walk": "two people walk side by side.",
    "run L": "two people run side by side, the second person on the first one's left.",
    "run R": "two people run side by side, the second person on the first one's right.",
    "bow back": "one person bows and the other bows back.",
    "bows": "two people bow to each other.",
    "spar": "two people spar, attacking each other in turn.",
    "greet": "two people face each other and greet each other.",
    "follow": "one person follows another.",
    "approach": "two people walk towards each other.",
    "part": "two people walk away from each other.",
}
PAIRS = [("walk L", "walk R"), ("walk L", "walk"), ("run L", "run R"), ("bow back", "bows"),
         ("spar", "greet"), ("walk", "bows"), ("walk", "approach")]  # fmt: skip


def centred_cosines(vectors, names: list[str]) -> dict[tuple[str, str], float]:
    import torch

    v = torch.nn.functional.normalize(vectors - vectors.mean(0), dim=-1)
    index = {n: i for i, n in enumerate(names)}
    return {(a, b): float(v[index[a]] @ v[index[b]]) for a, b in PAIRS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    args = ap.parse_args()

    import torch

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    names = list(PROMPTS)
    text = pipe.text_encoder.encode([PROMPTS[n] for n in names]).to(pipe.device)
    with torch.no_grad():
        rows = {"text encoder (pooled)": text.pooled.float(),
                "P-Flow text token": pipe.pflow.net.encode_text(text).float(),
                "S-Flow text token": pipe.sflow.net.encode_text(text).float()}  # fmt: skip
    table = {k: centred_cosines(v, names) for k, v in rows.items()}
    print(f"model {pipe.name}: centred cosine of the scene prompts' vectors (1: the same)")
    print(f"{'':24s}" + "".join(f"{a + ' / ' + b:>20s}" for a, b in PAIRS))
    for k, cos in table.items():
        print(f"{k:24s}" + "".join(f"{cos[p]:20.3f}" for p in PAIRS))


if __name__ == "__main__":
    main()
