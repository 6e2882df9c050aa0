"""Does ``torch.compile`` pay for the flows' networks? Eager against compiled, one run.

    python research/compile_speed.py [--model DIR] [--repeats 5] [--mode default]

Times, on the bundled model (or ``--model``), a 2-person 4-s scene (batch 1, clean-up off:
the networks' share) and a batch of 16: eager under the pipeline's ``no_grad``, under
``torch.inference_mode``, then with the P-Flow's and the S-Flow's
transformers compiled (``torch.compile(net, mode=...)``), after a warm-up that pays the
compilation (its time is reported). Each figure is the median of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

PROMPT = "Two people walk side by side."


def timed(fn, repeats: int) -> tuple[float, float]:
    """(first call's seconds, median of the next ``repeats``)."""
    start = time.perf_counter()
    fn()
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return first, statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--mode", default="default")
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    cases = {
        "1 scene": lambda: pipe(PROMPT, num_people=2, seconds=4.0, fit=False, separate=False),
        "batch 16": lambda: pipe(
            [PROMPT] * 16, num_people=2, seconds=4.0, fit=False, separate=False
        ),
    }
    eager = {k: timed(f, args.repeats) for k, f in cases.items()}

    def inference(f):
        def run():
            with torch.inference_mode():
                return f()

        return run

    inference_mode = {k: timed(inference(f), args.repeats) for k, f in cases.items()}
    for flow in (pipe.pflow, pipe.sflow):
        flow.net = torch.compile(flow.net, mode=args.mode)
    compiled = {k: timed(f, args.repeats) for k, f in cases.items()}
    print(f"model {pipe.name}; torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"torch.compile mode {args.mode!r}")  # fmt: skip
    for k in cases:
        (_, e), (_, i), (first, c) = eager[k], inference_mode[k], compiled[k]
        print(f"  {k}, N = 2, generator only: no_grad {e * 1000:.0f} ms, inference_mode "
              f"{i * 1000:.0f} ms -> {i / e:.2f}x the time")  # fmt: skip
        print(f"  {k}, N = 2, generator only: eager {e * 1000:.0f} ms, compiled {c * 1000:.0f} ms "
              f"-> {c / e:.2f}x the time (first compiled call {first:.1f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
