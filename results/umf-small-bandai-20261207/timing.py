"""Seconds per two-person scene (batch 1, median of 8 seeds) with and without own prompts.

    python results/umf-small-bandai-20261207/timing.py MODEL [MODEL ...]
"""

import statistics
import sys
import time

from umf.pipeline import UMFPipeline

SCENE = "Two people stand facing each other."
OWN = ["Someone bows politely.", "A person raises both hands."]

for model in sys.argv[1:]:
    pipe = UMFPipeline.from_pretrained(model)
    pipe(SCENE, num_people=2, seed=0)  # warm-up
    for own in (None, OWN):
        times = []
        for s in range(8):
            t0 = time.perf_counter()
            scene = pipe(SCENE, num_people=2, seed=s, person_prompts=own)[0]
            times.append(time.perf_counter() - t0)
        print(pipe.name, "own" if own else "scene only",
              f"{statistics.median(times):.3f} s median", "nfe", scene.meta["nfe"])  # fmt: skip
