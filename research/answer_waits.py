"""Do answers wait? Person 2's action onset after person 1's, for answering prompts.

For each prompt and duration, seeds 0..N-1, raw output (``fit=False, separate=False``, as
the protocol scores it): how many seeds have person 2 start at least 8 frames after person 1
(the checks' reading, :func:`umf.data.relations.action_onset` averaged over
``ONSET_SMOOTHING``), and the median gap, with the model's ``sflow.warm_timing`` and with
it off.

    python research/answer_waits.py [MODEL_DIR] [--seeds 12]
"""

from __future__ import annotations

import argparse

import numpy as np

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=12)
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


if __name__ == "__main__":
    main()
