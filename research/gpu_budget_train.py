"""Train the `small` family on one GPU within a fixed time budget (what made the bundled model).

Used on a lent GPU machine with a hard device-time limit, over a corpus unpacked by
``scripts/corpus_pack.py`` (``out/corpus``, text features included):

    python research/gpu_budget_train.py smoke        # time a VAE step (and the paper VAE's)
    python research/gpu_budget_train.py full 520     # flows timed, then VAE/P-Flow/S-Flow
                                                    # sized to fill 520 s, exported to $OUT

``full`` gives the VAE 45 % of what is left after timing, P-Flow 60 % of the rest, S-Flow
the remainder, with latent-bank start-up costs measured first. Environment: ``OUT``
(exported model tars and metrics), ``RUNS`` (run directories), ``CORPUS``, ``ACCEL``,
``WORKERS``, ``VBS`` / ``FBS`` (batch sizes), ``PASSES``, ``STEP_SCALE`` (dry runs).
"""

import json
import os
import sys
import tarfile
import time
from pathlib import Path

import torch

from umf.train.run import Launch, export_model, resolve_config, train_stage

OUT = Path(os.environ.get("OUT", "/tmp/out"))
CORPUS = Path(os.environ.get("CORPUS", "out/corpus"))
RUNS = Path(os.environ.get("RUNS", "/root/runs"))
launch = Launch(accelerator=os.environ.get("ACCEL", "gpu"), progress=False)
W = int(os.environ.get("WORKERS", 12))
VBS = int(os.environ.get("VBS", 128))
FBS = int(os.environ.get("FBS", 256))
PASSES = int(os.environ.get("PASSES", 8))
K = float(os.environ.get("STEP_SCALE", 1))  # local dry runs: fewer steps
torch.backends.cuda.matmul.allow_tf32 = True
torch.backends.cudnn.allow_tf32 = True


def timed(stage, run, cfg, steps):
    steps = None if steps is None else max(2, int(steps * K))
    t0 = time.time()
    res = train_stage(stage, CORPUS, run, cfg, launch, resume=True, max_steps=steps)
    dt = time.time() - t0
    print(
        f"== {stage} -> {steps} steps: {dt:.1f} s; {json.dumps(res, default=str)[:300]}", flush=True
    )
    return dt, res


def common(passes=PASSES):
    return [
        f"train_vae.batch_size={VBS}",
        f"train_vae.num_workers={W}",
        f"train_pflow.batch_size={FBS}",
        f"train_sflow.batch_size={FBS}",
        f"train_pflow.num_workers={W}",
        f"train_sflow.num_workers={W}",
        f"train_pflow.latent_passes={passes}",
        f"train_sflow.latent_passes={passes}",
        "train_vae.log_every=25",
        "train_pflow.log_every=25",
        "train_sflow.log_every=25",
    ]


def smoke():
    info = {
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
        "torch": torch.__version__,
    }
    run = RUNS / "smoke"
    cfg = resolve_config(
        run, "small", None, [*common(), "train_vae.val_every=1000", "train_vae.ckpt_every=1000"]
    )
    dt, res = timed("vae", run, cfg, 60)
    info["vae_s_per_step"] = res["seconds_per_step"]
    info["vae_start_s"] = dt - res["seconds"]
    prun = RUNS / "paper"
    pcfg = resolve_config(
        prun,
        "paper",
        None,
        [
            f"train_vae.num_workers={W}",
            "train_vae.log_every=5",
            "train_vae.val_every=1000",
            "train_vae.ckpt_every=1000",
        ],
    )
    if os.environ.get("SKIP_PAPER"):
        return _write_timing(info)
    dt, res = timed("vae", prun, pcfg, 25)
    info["paper_vae_s_per_step_b128"] = res["seconds_per_step"]
    _write_timing(info)


def _write_timing(info):
    print("TIMING", json.dumps(info), flush=True)
    (RUNS / "timing.json").write_text(json.dumps(info))
    (OUT / "timing.json").write_text(json.dumps(info))


def save_back(run, tag):
    """Metrics and config of ``run`` so far, as one tar under $OUT (the model comes at the end)."""
    with tarfile.open(OUT / f"metrics-{tag}.tar", "w") as tf:
        for p in run.glob("*/metrics.csv"):
            tf.add(p, arcname=f"{p.parent.name}/metrics.csv")
        if (run / "config.yaml").exists():
            tf.add(run / "config.yaml", arcname="config.yaml")


def full(budget):
    t0 = time.time()
    info = json.loads((RUNS / "timing.json").read_text())
    srun = RUNS / "smoke"
    scfg = resolve_config(srun, "small", None, common(passes=1))
    flow = {}
    for st in ("pflow", "sflow"):
        dt, res = timed(st, srun, scfg, 40)
        flow[st] = {
            "step": max(res["seconds_per_step"] or 0.05, 0.005),
            "start": dt - res["seconds"],
        }
    print("FLOW TIMING", json.dumps(flow), flush=True)
    left = budget - (time.time() - t0) - 50
    vs = info["vae_s_per_step"] * 1.1
    vae_steps = max(500, int(0.45 * left / vs) // 100 * 100)
    plan = {"vae": vae_steps}
    run = RUNS / "full"
    ov = [
        *common(),
        f"train_vae.max_steps={vae_steps}",
        "train_vae.warmup_steps=300",
        "train_vae.val_every=1000",
        "train_vae.ckpt_every=1000",
    ]
    cfg = resolve_config(run, "small", None, ov)
    print("PLAN vae", vae_steps, "left", round(left), flush=True)
    timed("vae", run, cfg, None)
    save_back(run, "vae")
    for st, share in (("pflow", 0.6), ("sflow", 1.0)):
        left = budget - (time.time() - t0) - 45
        # bank of 8 passes: about 8x the 1-pass start-up, measured above
        avail = share * left - 4 * flow[st]["start"]
        steps = max(300, int(avail / (flow[st]["step"] * 1.15)) // 100 * 100)
        plan[st] = steps
        ov += [
            f"train_{st}.max_steps={steps}",
            f"train_{st}.warmup_steps=300",
            f"train_{st}.val_every=500",
            f"train_{st}.ckpt_every=500",
        ]
        cfg = resolve_config(run, "small", None, ov)
        print("PLAN", st, steps, "left", round(left), flush=True)
        timed(st, run, cfg, None)
        save_back(run, st)
    model = RUNS / "model"
    export_model(run, model)
    names = sorted(p.name for p in model.iterdir())
    with tarfile.open(OUT / "model-a.tar", "w") as tf:
        for n in names:
            if n in ("vae.safetensors", "pflow.safetensors"):
                tf.add(model / n, arcname=n)
    with tarfile.open(OUT / "model-b.tar", "w") as tf:
        for n in names:
            if n not in ("vae.safetensors", "pflow.safetensors"):
                tf.add(model / n, arcname=n)
    (OUT / "plan.json").write_text(
        json.dumps({"plan": plan, "flow": flow, "seconds": time.time() - t0})
    )
    print("DONE", json.dumps(plan), round(time.time() - t0), flush=True)


if __name__ == "__main__":
    if sys.argv[1] == "smoke":
        smoke()
    else:
        full(float(sys.argv[2]))
