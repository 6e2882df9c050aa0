"""Speed of the bundled (or any) model on this machine: a benchmark, not a test.

Prints, and writes as JSON with ``--out``:
- seconds to load the model (text encoder included);
- seconds per scene for N = 1, 2, 4, 8 people at the model's default step budget;
- scenes per second when 16 scenes are sampled together;
- P-Flow with its pyramid against the same network run without it (every step at full
  resolution) at an equal number of steps, both measured in this run.

    python scripts/benchmark.py [--model DIR] [--repeats 5] [--out results/benchmark.json]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import torch

PROMPT = "two people bow to each other"


def timed(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` over ``repeats`` runs after one warm-up run."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def flat_pflow(pipe):
    """The same P-Flow network sampled without the pyramid: one full-resolution stage.

    Shares every weight with the model's own P-Flow; only the schedule differs, which
    is what the pyramid's speed-up is about.
    """
    import dataclasses

    from umf.models.pflow import PFlow

    # one stage over the whole time axis, guided like the model's coarse stages
    cfg = dataclasses.replace(pipe.config.pflow, num_stages=1, starts=None, fine_guidance=None)
    p, r = pipe.vae.latent_shape
    flat = PFlow(cfg, p, r, pipe.text_encoder.dim)
    missing, unexpected = flat.load_state_dict(pipe.pflow.state_dict(), strict=False)
    if unexpected or missing:
        shared = len(pipe.pflow.state_dict()) - len(unexpected)
        print(f"  (no-pyramid P-Flow: {shared} tensors shared, {len(missing)} fresh)")
    return flat.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="model dir (default: bundled)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args()

    from umf.pipeline import UMFPipeline

    start = time.perf_counter()
    pipe = UMFPipeline.from_pretrained(args.model)
    load_s = time.perf_counter() - start
    steps = list(pipe.config.pflow.steps)
    sflow_steps, pair_steps = pipe.config.sflow.steps, pipe.config.sflow.steps_for(2)
    print(f"model {pipe.name}: loaded in {load_s:.2f} s; steps P-Flow {steps}, "
          f"S-Flow {sflow_steps} per person ({pair_steps} for two people); "
          f"torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")  # fmt: skip

    per_scene = {}
    for n in (1, 2, 4, 8):
        s = timed(lambda n=n: pipe(PROMPT, num_people=n, seconds=args.seconds), args.repeats)
        per_scene[n] = s
        print(f"  N = {n}: {s:.3f} s per scene")

    batch = 16
    s16 = timed(lambda: pipe([PROMPT] * batch, num_people=2, seconds=args.seconds),
                max(1, args.repeats // 2))  # fmt: skip
    print(f"  batch {batch}, N = 2: {batch / s16:.1f} scenes/s ({s16:.2f} s per batch)")

    # P-Flow alone, pyramid vs none, equal total steps, same weights
    text = pipe.text_encoder.encode([PROMPT])
    uncond = pipe.text_encoder.encode([""])
    flat = flat_pflow(pipe)
    total = sum(steps)

    def run(model, st):
        return lambda: model.sample(text, uncond, steps=st, generator=torch.Generator())

    pyr = timed(run(pipe.pflow, steps), args.repeats)
    full = timed(run(flat, [total]), args.repeats)
    print(f"  P-Flow {total} steps: pyramid {steps} {pyr * 1000:.1f} ms, no pyramid "
          f"{full * 1000:.1f} ms -> pyramid takes {pyr / full:.2f}x the time")  # fmt: skip

    figures = {
        "model": pipe.name,
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "seconds_of_motion": args.seconds,
        "load_s": round(load_s, 3),
        "pflow_steps": steps,
        "sflow_steps": sflow_steps,
        "sflow_pair_steps": pair_steps,
        "s_per_scene": {str(k): round(v, 4) for k, v in per_scene.items()},
        "batch16_scenes_per_s": round(batch / s16, 2),
        "pflow_pyramid_s": round(pyr, 5),
        "pflow_no_pyramid_s": round(full, 5),
        "pyramid_time_ratio": round(pyr / full, 3),
    }
    if args.out:
        from umf.io import write_json_atomic

        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.out, figures)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
