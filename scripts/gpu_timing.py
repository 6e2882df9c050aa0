"""Speed on a GPU: the bundled model and the paper family's size, batch 1 and 64.

    python scripts/gpu_timing.py [--model DIR] [--device cuda] [--repeats 5] [--out FILE]

The CPU benchmark (``scripts/benchmark.py``) answers for the machine the project is built
on; this one answers for the machine a research user trains on. Per family (the bundled
small model; the paper family with random weights, since time does not depend on them),
per batch (1, 64) and people (2, 8), 4 s of motion:

- ``generator_s``: text, P-Flow, S-Flow and the VAE on the GPU (``fit=False,
  separate=False``), synchronised, median of ``--repeats`` after a warm-up;
- ``pipeline_s`` (the bundled model only): the default call with its clean-up (anchoring
  and separation on the CPU, the rigid-body fit of the whole chunk on the device);
- FLOPs of the generator call and its rate against a large fp32 (and TF32) matmul timed in
  the same run;
- P-Flow with its pyramid against the same network without it (``benchmark.flat_pflow``)
  at equal steps, per family and batch;
- the clean-up of the last batch fitted in one solve on the device against scene by
  scene on the CPU: seconds and the largest joint difference;
- where the bundled model's default call spends its time (text, P-Flow, S-Flow, VAE,
  clean-up), per batch;
- the FreeMotion-class baseline (``umf.eval.freemotion``, random weights) at N = 2 and 8,
  batch 1: each network evaluation timed on the GPU, times its 50 DDIM steps, so the
  paper's "about 5x faster" reads on a GPU too.

Runs on the CPU as well (``--device cpu``), which is how it is tested; a GPU that is asked
for and absent is a one-line error.
"""

from __future__ import annotations

import argparse
import functools
import platform
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
import benchmark

PROMPT = benchmark.PROMPT
FREEMOTION_FPS = benchmark.FREEMOTION_FPS  # InterHuman's: 4 s = 120 frames


def synced_timer(device: torch.device):
    """(``timed(fn, repeats)``, ``sync``): the benchmark's median-after-warm-up timer with
    the device synchronised before each clock read (CUDA work is asynchronous)."""

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    return functools.partial(benchmark.timed, sync=sync), sync


def matmul_rates(device: torch.device, timed, n: int = 4096) -> dict[str, float]:
    """GFLOP/s of an (n x n) @ (n x n) fp32 matmul, and with TF32 allowed on a GPU."""
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    rates = {"fp32": 2 * n**3 / timed(lambda: a @ b, 5) / 1e9}
    if device.type == "cuda":
        old = torch.backends.cuda.matmul.allow_tf32
        torch.backends.cuda.matmul.allow_tf32 = True
        try:
            rates["tf32"] = 2 * n**3 / timed(lambda: a @ b, 5) / 1e9
        finally:
            torch.backends.cuda.matmul.allow_tf32 = old
    return {k: round(v, 1) for k, v in rates.items()}


def freemotion_s(device: torch.device, timed, people: int, frames: int) -> float:
    """Seconds of one FreeMotion-class scene on ``device``: DDIM steps x (person 1's guided
    evaluation + each follower's, with everyone before it)."""
    from umf.eval.freemotion import FreeMotionConfig, FreeMotionNet

    torch.manual_seed(0)
    net = FreeMotionNet(FreeMotionConfig()).to(device).eval()
    cfg = net.cfg
    text = torch.randn(2, 77, cfg.text_dim, device=device)  # the guided pair in one batch
    steps = torch.full((2,), 500, dtype=torch.long, device=device)
    x = torch.randn(2, frames, cfg.feature_dim, device=device)
    total = 0.0
    with torch.inference_mode():
        for k in range(people):
            others = None if k == 0 else torch.randn(2, k, frames, cfg.feature_dim, device=device)
            total += cfg.steps * timed(functools.partial(net, x, steps, text, others), 3)
    return total


def family_rows(pipe, family: str, timed, repeats: int, batches, peoples, full_batches):
    """One row per (batch, people): generator seconds, FLOPs and rate; the default call's
    seconds where ``batch in full_batches``."""
    from umf.eval.flops import count_flops

    rows = []
    for batch in batches:
        prompts = [PROMPT] * batch
        for n in peoples:
            gen = functools.partial(pipe, prompts, num_people=n, seconds=4.0, fit=False,
                                    separate=False)  # fmt: skip
            s = timed(gen, repeats)
            flops = count_flops(gen)
            row = {"family": family, "batch": batch, "people": n, "generator_s": round(s, 5),
                   "scenes_per_s": round(batch / s, 2), "gflop": round(flops / 1e9, 2),
                   "gflops_per_s": round(flops / s / 1e9, 1)}  # fmt: skip
            if batch in full_batches:
                full = functools.partial(pipe, prompts, num_people=n, seconds=4.0)
                row["pipeline_s"] = round(timed(full, max(1, repeats // 2)), 4)
            rows.append(row)
            extra = f", default call {row['pipeline_s']:.3f} s" if "pipeline_s" in row else ""
            print(f"  {family:5s} batch {batch:2d}, N = {n}: generator {s * 1000:.1f} ms "
                  f"({row['scenes_per_s']:.1f} scenes/s, {row['gflops_per_s']:.0f} GFLOP/s)"
                  f"{extra}", flush=True)  # fmt: skip
    return rows


def decoded_batch(pipe, batch: int):
    """Raw decoded joints (B, 2, T, 22, 3) and contact labels (B, 2, T, 4) of ``batch``
    generated two-person scenes: the clean-up's input."""
    import numpy as np

    from umf.representation import CONTACT

    scenes = pipe([PROMPT] * batch, num_people=2, seconds=4.0, fit=False, separate=False)
    return (np.stack([s.joints for s in scenes]),
            np.stack([s.features[..., CONTACT] for s in scenes]))  # fmt: skip


def fit_agreement(pipe, timed, batch: int) -> dict:
    """The clean-up of ``batch`` generated two-person scenes both ways: every person of
    every scene fitted in one solve on ``pipe``'s device, and scene by scene on the CPU
    (what the pipeline did before); seconds of each and the largest joint difference."""
    import numpy as np

    from umf.pipeline import clean_up_scenes

    decoded, contacts = decoded_batch(pipe, batch)
    merged = functools.partial(clean_up_scenes, decoded, contacts, device=pipe.device, merge=True)
    apart = functools.partial(clean_up_scenes, decoded, contacts, merge=False)
    one, two = merged(), apart()
    pairs = zip(one[1], two[1], strict=True)
    gap = max(float(np.abs(a.joints() - b.joints()).max()) for a, b in pairs)
    row = {"batch": batch, "merged_on_device_s": round(timed(merged, 3), 4),
           "scene_by_scene_cpu_s": round(timed(apart, 1), 4),
           "max_joint_gap_mm": gap * 1000}  # fmt: skip
    print(f"  clean-up of {batch} scenes: one fit on {pipe.device} {row['merged_on_device_s']:.3f}"
          f" s, scene by scene on the CPU {row['scene_by_scene_cpu_s']:.3f} s; joints agree "
          f"within {row['max_joint_gap_mm']:.4f} mm", flush=True)  # fmt: skip
    return row


def profile_clean_up(pipe, batch: int, top: int = 25) -> None:
    """cProfile of one merged clean-up of ``batch`` two-person scenes on ``pipe``'s device,
    the functions by their own time (run with CUDA_LAUNCH_BLOCKING=1 so that a kernel's
    time lands on the call that launched it)."""
    import cProfile
    import pstats

    from umf.pipeline import clean_up_scenes

    decoded, contacts = decoded_batch(pipe, batch)
    clean_up_scenes(decoded, contacts, device=pipe.device, merge=True)  # warm-up
    prof = cProfile.Profile()
    prof.enable()
    clean_up_scenes(decoded, contacts, device=pipe.device, merge=True)
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)
    pstats.Stats(prof).sort_stats("cumtime").print_stats(top)


def compiled_rows(pipe, timed, repeats: int, batches) -> list[dict]:
    """The bundled model's generator (N = 2) with the P-Flow's and S-Flow's transformers
    under ``torch.compile``: seconds of the first call (the compilation) and after it."""
    rows = []
    for flow in (pipe.pflow, pipe.sflow):
        flow.net = torch.compile(flow.net)
    for batch in batches:
        gen = functools.partial(pipe, [PROMPT] * batch, num_people=2, seconds=4.0, fit=False,
                                separate=False)  # fmt: skip
        start = time.perf_counter()
        gen()
        first = time.perf_counter() - start
        s = timed(gen, repeats)
        rows.append({"batch": batch, "people": 2, "first_call_s": round(first, 2),
                     "generator_s": round(s, 5)})  # fmt: skip
        print(f"  small batch {batch:2d}, N = 2, compiled: generator {s * 1000:.1f} ms "
              f"(first call {first:.1f} s)", flush=True)  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", type=Path, default=None, help="model dir (default: bundled)")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64])
    ap.add_argument("--people", type=int, nargs="+", default=[2, 8])
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument(
        "--profile-clean-up",
        action="store_true",
        help="only profile (cProfile) the merged clean-up of a batch of the last size, and exit",
    )
    ap.add_argument(
        "--compile",
        action="store_true",
        help="then time the bundled model with its flows' networks compiled",
    )
    args = ap.parse_args(argv)

    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        sys.exit("gpu_timing: --device cuda asked for, but torch sees no CUDA device")
    from umf.config import family_config
    from umf.pipeline import UMFPipeline

    timed, sync = synced_timer(device)
    if args.profile_clean_up:
        profile_clean_up(UMFPipeline.from_pretrained(args.model).to(device), args.batches[-1])
        return {}
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor()
    print(f"device {device} ({name}); torch {torch.__version__}", flush=True)
    small = UMFPipeline.from_pretrained(args.model).to(device)
    paper = UMFPipeline.build(family_config("paper"), text_encoder=small.text_encoder).to(device)
    rows = family_rows(small, "small", timed, args.repeats, args.batches, args.people,
                       full_batches=args.batches)  # fmt: skip
    rows += family_rows(
        paper, "paper", timed, args.repeats, args.batches, args.people, full_batches=()
    )  # random weights: only the generator's time
    stages, pyramid = {}, {}
    for fam, pipe in (("small", small), ("paper", paper)):
        for batch in args.batches:
            pyr, flat = benchmark.pyramid_vs_flat(pipe, args.repeats, sync, batch)
            pyramid[f"{fam}_b{batch}"] = {"pyramid_s": round(pyr, 5), "flat_s": round(flat, 5),
                                          "ratio": round(pyr / flat, 3)}  # fmt: skip
            print(f"  {fam:5s} batch {batch:2d}, P-Flow {list(pipe.config.pflow.steps)}: "
                  f"pyramid {pyr * 1000:.1f} ms, flat {flat * 1000:.1f} ms -> "
                  f"{pyr / flat:.2f}x", flush=True)  # fmt: skip
    for batch in args.batches:
        prof = benchmark.stage_profile(small, 2, 4.0, max(1, args.repeats // 2), sync, batch)
        stages[f"small_b{batch}_n2"] = {k: round(v, 5) for k, v in prof.items()}
        print(
            f"  small batch {batch:2d}, N = 2, stages: "
            + ", ".join(f"{k} {v * 1000:.0f} ms" for k, v in prof.items()),
            flush=True,
        )
    agreement = fit_agreement(small, timed, args.batches[-1])
    base = {n: freemotion_s(device, timed, n, round(4.0 * FREEMOTION_FPS)) for n in args.people}
    rates = matmul_rates(device, timed)

    def one(family, batch, n):
        return next(r for r in rows if (r["family"], r["batch"], r["people"]) == (family, batch, n))

    speedup = {}
    for n in args.people:
        b1 = args.batches[0]
        for fam in ("small", "paper"):
            speedup[f"{fam}_n{n}_generator"] = round(base[n] / one(fam, b1, n)["generator_s"], 1)
        speedup[f"small_n{n}_pipeline"] = round(base[n] / one("small", b1, n)["pipeline_s"], 1)
        print(f"  FreeMotion-class N = {n}: {base[n]:.2f} s per scene -> UMF small "
              f"{speedup[f'small_n{n}_pipeline']}x (default call), paper size "
              f"{speedup[f'paper_n{n}_generator']}x (generator)", flush=True)  # fmt: skip
    best = max(r["gflops_per_s"] for r in rows)
    print(f"  matmul {rates}: best generator rate {best:.0f} GFLOP/s = "
          f"{best / rates['fp32']:.0%} of fp32", flush=True)  # fmt: skip
    compiled = compiled_rows(small, timed, args.repeats, args.batches) if args.compile else []
    figures = {
        "device": name,
        "torch": torch.__version__,
        "model": small.name,
        "pflow_steps": list(small.config.pflow.steps),
        "sflow_steps": small.config.sflow.steps,
        "rows": rows,
        "pyramid_vs_flat": pyramid,
        "clean_up": agreement,
        "stage_s": stages,
        "freemotion_s": {str(n): round(s, 4) for n, s in base.items()},
        "freemotion_speedup": speedup,
        "matmul_gflops_per_s": rates,
        "compiled": compiled,
    }
    if args.out:
        from umf.io import write_json_atomic

        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.out, figures)
        print(f"wrote {args.out}")
    return figures


if __name__ == "__main__":
    main()
