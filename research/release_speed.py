"""Seconds per two-person scene of two model directories, in one process, alternating.

    python research/release_speed.py NAME=MODEL_DIR NAME=MODEL_DIR [--rounds 3]

Five prompts (walk and run side by side, a bow back, salsa, a greeting) at two seeds each,
4 s, raw output (``fit=False, separate=False``: the sampling, not the clean-up), after one
warm-up scene per model; the mean per scene of each round. The protocol's own speed row is
measured once per run and moves with the machine's load; this compares releases under the
same load.
"""

from __future__ import annotations

import argparse
import time

import torch

PROMPTS = ["Two people walk side by side.", "Two people run side by side.",
           "One person bows and the other bows back.", "Two people dance salsa together.",
           "Two people face each other and greet."]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="NAME=MODEL_DIR (MODEL_DIR 'bundled': the default)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    torch.set_grad_enabled(False)
    pipes = {}
    for item in args.models:
        name, _, path = item.partition("=")
        pipes[name] = UMFPipeline.from_pretrained(None if path in ("", "bundled") else path)
    for pipe in pipes.values():
        pipe(PROMPTS[0], num_people=2, seconds=4.0, seed=0)
    times: dict[str, list[float]] = {name: [] for name in pipes}
    for _ in range(args.rounds):
        for name, pipe in pipes.items():
            start = time.perf_counter()
            for i, prompt in enumerate(PROMPTS * 2):
                pipe(prompt, num_people=2, seconds=4.0, seed=i, fit=False, separate=False)
            times[name].append((time.perf_counter() - start) / (2 * len(PROMPTS)))
    for name, t in times.items():
        print(f"{name}: " + ", ".join(f"{x:.3f}" for x in t) + " s per scene")


if __name__ == "__main__":
    main()
