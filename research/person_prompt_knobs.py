"""Does any sampling knob make person 2 raise both hands on command? The settings tried for
the per-person prompts issue, measured on a model.

    python research/person_prompt_knobs.py [--model DIR] [--seeds 8]

"Two people stand facing each other." with person prompts "Someone bows politely." /
"A person raises both hands." (person 2 told to raise them), seeds 0..N-1, 4 s: for each own-
prompt guidance (``person_guidance`` 2, 3, 4 with the scene's at its default) and 10 S-Flow
steps (at the model's own guidance), how many seeds have person 2's lower wrist above the
head and person 1's head more than 8 cm down, raw (``fit=False, separate=False``) and
delivered, with person 2's wrist heights; and person 2 under the scene prompt "Two people
raise both hands." alone.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

SCENE = "Two people stand facing each other."
HANDS, BOW = "A person raises both hands.", "Someone bows politely."


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    from umf.eval.motion_stats import motion_statistics
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    n = args.seeds
    kw = dict(num_people=2, seed=0, sample_indices=range(n))
    shipped = {flow: flow.cfg.person_guidance for flow in (pipe.pflow, pipe.sflow)}
    print(f"model {pipe.name}; {n} seeds, 4 s; scene {SCENE!r}, P1 {BOW!r}, P2 {HANDS!r}")
    for setting in ({"person_guidance": 2.0}, {"person_guidance": 3.0},
                    {"person_guidance": 4.0}, {"sflow_steps": 10}):  # fmt: skip
        for flow in (pipe.pflow, pipe.sflow):
            flow.cfg.person_guidance = setting.get("person_guidance", shipped[flow])
        steps = {"sflow_steps": setting["sflow_steps"]} if "sflow_steps" in setting else {}
        for stage, extra in (("raw", {"fit": False, "separate": False}), ("delivered", {})):
            scenes = pipe([SCENE] * n, person_prompts=[BOW, HANDS], **kw, **steps, **extra)
            rows = [[motion_statistics(s.joints[k]) for k in range(2)] for s in scenes]
            hands = [r[1]["both_wrists_above_head"] for r in rows]
            bows = sum(r[0]["head_drop"] > 0.08 for r in rows)
            print(f"  {setting} {stage:9s} P2 hands {sum(h > 0 for h in hands)}/{n} "
                  f"({' '.join(f'{h:.2f}' for h in hands)} m), P1 bows {bows}/{n}")  # fmt: skip
    scenes = pipe(["Two people raise both hands."] * n, **kw)
    hands = [motion_statistics(s.joints[1])["both_wrists_above_head"] for s in scenes]
    print(
        f"  scene prompt 'Two people raise both hands.', delivered: P2 hands "
        f"{sum(h > 0 for h in hands)}/{n} ({' '.join(f'{h:.2f}' for h in hands)} m)"
    )
    print(f"  P2 wrist below head, median {-np.median(hands):.2f} m")


if __name__ == "__main__":
    main()
