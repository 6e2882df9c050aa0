"""Where person 2 stands: the pelvis floor distance between persons 1 and 2, mean over the
frames and at the first frame, raw (no clean-up, no separation), seeds 0-3, 4 s.

    python pair_distances.py MODEL [MODEL ...]
"""

import sys

import numpy as np

from umf.pipeline import UMFPipeline

PROMPTS = ["Two people walk side by side.", "Two people bow to each other.",
           "One person kicks toward the other, who steps back.",
           "Two people stand facing each other.", "Two people shake hands."]  # fmt: skip

for model in sys.argv[1:]:
    pipe = UMFPipeline.from_pretrained(model)
    print(model)
    for prompt in PROMPTS:
        mean, first = [], []
        for seed in range(4):
            scene = pipe(prompt, num_people=2, seconds=4.0, seed=seed, fit=False, separate=False)[0]
            p = np.asarray(scene.joints)[:, :, 0, [0, 2]]
            d = np.linalg.norm(p[1] - p[0], axis=-1)
            mean.append(d.mean())
            first.append(d[0])
        print(f"  {prompt[:40]:40s} mean {np.round(mean, 2)}  first {np.round(first, 2)}")
