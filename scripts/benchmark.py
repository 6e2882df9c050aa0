"""Speed of the bundled (or any) model on this machine: a benchmark, not a test.

Prints, and writes as JSON with ``--out``:
- seconds to load the model (text encoder included);
- seconds per scene for N = 1, 2, 4, 8 people at the model's default step budget;
- scenes per second when 16 scenes are sampled together;
- P-Flow with its pyramid against the same network run without it (every step at full
  resolution) at an equal number of steps, both measured in this run, for the model and for
  the paper family's size (random weights: time does not depend on them);
- where a 2-person scene's time goes (text, P-Flow, S-Flow, VAE, clean-up);
- a FreeMotion-class baseline (`umf.eval.freemotion`, its published size, random weights)
  against UMF in the same run, N = 2, 4, 8 and 4 s / 10 s, FLOPs counted for both;
- a large fp32 matmul's rate, so that the batch throughput reads as a share of the machine.

    python scripts/benchmark.py [--model DIR] [--repeats 5] [--out results/benchmark.json]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import functools
import platform
import statistics
import time
from pathlib import Path

import torch

PROMPT = "two people bow to each other"
FREEMOTION_FPS = 30.0  # InterHuman's frame rate: 4 s = 120 frames, 10 s = 300


def no_sync() -> None:
    """The CPU's work is done when a call returns: nothing to wait for."""


def timed(fn, repeats: int, sync=no_sync) -> float:
    """Median wall time of ``fn()`` over ``repeats`` runs after one warm-up run; ``sync``
    waits for a device's queued work before each clock read (``torch.cuda.synchronize``)."""
    fn()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
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
    flat = PFlow(cfg, p, r, pipe.text_encoder.dim).to(pipe.device)
    missing, unexpected = flat.load_state_dict(pipe.pflow.state_dict(), strict=False)
    if unexpected or missing:
        shared = len(pipe.pflow.state_dict()) - len(unexpected)
        print(f"  (no-pyramid P-Flow: {shared} tensors shared, {len(missing)} fresh)")
    return flat.eval()


def matmul_gflops(n: int = 2048, repeats: int = 5) -> float:
    """GFLOP/s of an (n x n) @ (n x n) fp32 matmul: what this machine's cores can do."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    return 2 * n**3 / timed(lambda: a @ b, repeats) / 1e9


@contextlib.contextmanager
def stage_timer(pipe, sync=no_sync):
    """Seconds spent in each stage of the calls made inside, by wrapping the pipeline's
    text encoder, flows, VAE and clean-up (restored on exit; ``sync`` as in :func:`timed`)."""
    import umf.pipeline as pipeline_module

    spent: dict[str, float] = collections.defaultdict(float)

    def wrap(stage, fn):
        def timed_call(*args, **kwargs):
            sync()
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                sync()
                spent[stage] += time.perf_counter() - start

        return timed_call

    targets = [(pipe.text_encoder, "encode", "text"), (pipe.pflow, "sample", "P-Flow"),
               (pipe.sflow, "sample", "S-Flow"), (pipe, "_decode_raw", "VAE"),
               (pipe, "_encode", "VAE"),
               (pipeline_module, "clean_up_scenes", "clean-up")]  # fmt: skip
    saved = [(obj, name, obj.__dict__.get(name)) for obj, name, _ in targets]
    for obj, name, stage in targets:
        setattr(obj, name, wrap(stage, getattr(obj, name)))
    try:
        yield spent
    finally:
        for obj, name, old in saved:
            if old is None:
                delattr(obj, name)
            else:
                setattr(obj, name, old)


def stage_profile(
    pipe, num_people: int, seconds: float, repeats: int, sync=no_sync, batch: int = 1
) -> dict[str, float]:
    """Median seconds per stage of one call of ``batch`` scenes (and the rest, "other")."""
    prompts = [PROMPT] * batch
    pipe(prompts, num_people=num_people, seconds=seconds)  # warm-up
    runs = []
    for _ in range(repeats):
        with stage_timer(pipe, sync) as spent:
            start = time.perf_counter()
            pipe(prompts, num_people=num_people, seconds=seconds)
            sync()
            total = time.perf_counter() - start
        runs.append({**spent, "other": total - sum(spent.values()), "total": total})
    return {k: statistics.median(r.get(k, 0.0) for r in runs) for k in runs[0]}


def paper_pipe(text_encoder):
    """The paper family's UMF with random weights (same text encoder as the model)."""
    from umf.config import family_config
    from umf.pipeline import UMFPipeline

    return UMFPipeline.build(family_config("paper"), text_encoder=text_encoder)


def pyramid_vs_flat(pipe, repeats: int, sync=no_sync, batch: int = 1) -> tuple[float, float]:
    """Seconds of P-Flow sampling of ``batch`` prompts with the pyramid and without it,
    equal total steps."""
    text = pipe.text_encoder.encode([PROMPT] * batch)
    uncond = pipe.text_encoder.encode([""] * batch)
    steps = list(pipe.config.pflow.steps)
    flat = flat_pflow(pipe)

    def run(model, st):
        return lambda: model.sample(text, uncond, steps=st,
                                    generator=torch.Generator(pipe.device))  # fmt: skip

    with torch.inference_mode():
        return (timed(run(pipe.pflow, steps), repeats, sync),
                timed(run(flat, [sum(steps)]), repeats, sync))  # fmt: skip


def freemotion_scene_s(net, frames: int, people: int, repeats: int) -> tuple[float, int]:
    """Seconds and FLOPs of one FreeMotion-class scene: DDIM steps x (person 1's guided
    evaluation + each follower's, with everyone before it), each evaluation timed here."""
    from umf.eval.flops import count_flops

    cfg = net.cfg
    text = torch.randn(2, 77, cfg.text_dim)  # the guided pair in one batch
    steps = torch.full((2,), 500, dtype=torch.long)
    x = torch.randn(2, frames, cfg.feature_dim)
    seconds, flops = 0.0, 0
    with torch.inference_mode():
        for k in range(people):
            others = None if k == 0 else torch.randn(2, k, frames, cfg.feature_dim)
            call = functools.partial(net, x, steps, text, others)
            seconds += cfg.steps * timed(call, repeats)
            flops += cfg.steps * count_flops(call)
    return seconds, flops


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

    from umf.eval.flops import count_flops

    batch = 16
    prompts = [PROMPT] * batch
    s16 = timed(lambda: pipe(prompts, num_people=2, seconds=args.seconds),
                max(1, args.repeats // 2))  # fmt: skip
    print(f"  batch {batch}, N = 2: {batch / s16:.1f} scenes/s ({s16:.2f} s per batch)")

    def generator_only(p, n, seconds, prompts=PROMPT):
        return lambda: p(prompts, num_people=n, seconds=seconds, fit=False, separate=False)

    g16 = timed(generator_only(pipe, 2, args.seconds, prompts), max(1, args.repeats // 2))
    batch_flops = count_flops(generator_only(pipe, 2, args.seconds, prompts))
    matmul = matmul_gflops(repeats=args.repeats)
    batch_rate = batch_flops / g16 / 1e9
    print(f"  batch {batch}, N = 2, generator only (no clean-up): {g16:.2f} s, "
          f"{batch_flops / 1e9:.0f} GFLOP -> {batch_rate:.1f} GFLOP/s; a {2048}^2 fp32 matmul "
          f"runs at {matmul:.1f} GFLOP/s -> {batch_rate / matmul:.0%} of it")  # fmt: skip

    stages = stage_profile(pipe, 2, args.seconds, args.repeats)
    print("  one 2-person scene: " + ", ".join(f"{k} {v * 1000:.0f} ms" for k, v in stages.items()))

    pyr, full = pyramid_vs_flat(pipe, args.repeats)
    total = sum(steps)
    print(f"  P-Flow {total} steps: pyramid {steps} {pyr * 1000:.1f} ms, no pyramid "
          f"{full * 1000:.1f} ms -> pyramid takes {pyr / full:.2f}x the time")  # fmt: skip
    paper = paper_pipe(pipe.text_encoder)
    pyr_p, full_p = pyramid_vs_flat(paper, max(1, args.repeats // 2))
    print(f"  paper family (random weights), P-Flow: pyramid {pyr_p * 1000:.0f} ms, no pyramid "
          f"{full_p * 1000:.0f} ms -> {pyr_p / full_p:.2f}x")  # fmt: skip

    from umf.eval.freemotion import FreeMotionConfig, FreeMotionNet

    torch.manual_seed(0)
    net = FreeMotionNet(FreeMotionConfig()).eval()
    versus = []
    for seconds in (4.0, 10.0):
        frames = round(seconds * FREEMOTION_FPS)
        for n in (2, 4, 8):
            base_s, base_flops = freemotion_scene_s(net, frames, n, max(1, args.repeats // 2))
            ours = timed(lambda n=n, s=seconds: pipe(PROMPT, num_people=n, seconds=s), 1)
            gen = generator_only(pipe, n, seconds)
            ours_gen = timed(gen, 1)
            paper_gen = timed(generator_only(paper, n, seconds), 1)
            row = {"seconds": seconds, "people": n, "freemotion_s": round(base_s, 3),
                   "umf_s": round(ours, 4), "umf_generator_s": round(ours_gen, 4),
                   "umf_paper_generator_s": round(paper_gen, 4),
                   "freemotion_gflop": round(base_flops / 1e9, 1),
                   "umf_gflop": round(count_flops(gen) / 1e9, 2),
                   "umf_paper_gflop": round(count_flops(generator_only(paper, n, seconds)) / 1e9,
                                            1)}  # fmt: skip
            versus.append(row)
            print(f"  {seconds:.0f} s, N = {n}: FreeMotion-class {base_s:.1f} s "
                  f"({row['freemotion_gflop']:.0f} GFLOP); UMF {ours:.2f} s "
                  f"({row['umf_gflop']:.1f} GFLOP) -> {base_s / ours:.0f}x; paper-size UMF "
                  f"{paper_gen:.2f} s ({row['umf_paper_gflop']:.0f} GFLOP) -> "
                  f"{base_s / paper_gen:.1f}x")  # fmt: skip

    def speedup(n, key):
        row = next(r for r in versus if r["people"] == n and r["seconds"] == 4.0)
        return round(row["freemotion_s"] / row[key], 2)

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
        "batch16_generator_s": round(g16, 4),
        "batch_gflops_per_s": round(batch_rate, 2),
        "matmul_gflops_per_s": round(matmul, 2),
        "batch_share_of_matmul": round(batch_rate / matmul, 4),
        "stage_s_n2": {k: round(v, 4) for k, v in stages.items()},
        "pflow_pyramid_s": round(pyr, 5),
        "pflow_no_pyramid_s": round(full, 5),
        "pyramid_time_ratio": round(pyr / full, 3),
        "pflow_pyramid_s_paper": round(pyr_p, 5),
        "pflow_no_pyramid_s_paper": round(full_p, 5),
        "pyramid_time_ratio_paper": round(pyr_p / full_p, 3),
        "baseline": "FreeMotion-class (umf.eval.freemotion): 8 x 1024, DDIM 50 + CFG, "
        "ControlNet copy per added person; each evaluation timed, x 50 steps",
        "versus_freemotion": versus,
        "baseline_speedup_n2": speedup(2, "umf_s"),
        "baseline_speedup_n8": speedup(8, "umf_s"),
        "baseline_speedup_n2_paper": speedup(2, "umf_paper_generator_s"),
        "baseline_speedup_n8_paper": speedup(8, "umf_paper_generator_s"),
    }
    if args.out:
        from umf.io import write_json_atomic

        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.out, figures)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
