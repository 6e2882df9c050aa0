"""Train a model's flows on one GPU, side by side, within a fixed time budget.

P-Flow and S-Flow only depend on the frozen VAE, so on a lent GPU with a hard time limit
they can train at the same time in two processes (the small family's flows are far from
filling a GPU: a step is launch-bound, not compute-bound). The VAE is taken from an
existing model directory (the bundled one by default) and is not retrained, unless
``--vae`` is given: then a new VAE of the ``small`` family (with the ``--set`` options)
trains first, and the flows train on it.

    python scripts/corpus_pack.py unpack .gpu out/corpus          # on the GPU node
    python scripts/gpu_flows_train.py 540 --set train_pflow.max_steps=3500 ...
    python scripts/gpu_flows_train.py 560 --vae --set vae.num_tokens=32 --set vae.token_span=5.0 \
        --set train_vae.max_steps=2000 --set train_vae.batch_size=128 ...

Where what one call may carry is capped (the motion and the text features do not travel
together), ``--vae-only`` trains the VAE in a first call (the motion only) and stops; the
same command without it, in a second call on the same machine, finds that VAE finished
(``RUNS``/flows/vae/finished) and trains the flows on it.

The first argument is the wall-clock budget in seconds for everything: a flow still
running then is stopped and the model is exported from the best checkpoints written so far
(atomic, every ``ckpt_every`` steps); a VAE still running then ends the run (the flows need
it finished). Size ``max_steps`` so that each cosine schedule ends within the budget: a
stopped stage has not annealed its learning rate. The exported ``config.json`` records the
loader settings of whichever flow finished last. Environment: ``OUT`` (exported model,
metrics and logs), ``RUNS`` (run directory parent), ``CORPUS``, ``MODEL`` (where the frozen
VAE comes from), ``PFLOW_WORKERS`` / ``SFLOW_WORKERS`` / ``VAE_WORKERS`` (loader
processes; the flows' while their latent banks are built).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

OUT = Path(os.environ.get("OUT", "/tmp/out"))
CORPUS = Path(os.environ.get("CORPUS", "out/corpus"))
RUNS = Path(os.environ.get("RUNS", "/root/runs"))
MODEL = Path(os.environ.get("MODEL", "src/umf/assets/model"))


def child(stage: str, run: Path, plan: Path) -> None:
    """One stage, trained to its configured ``max_steps`` (or until the parent stops it)."""
    import torch

    from umf.config import UMFConfig
    from umf.train.run import Launch, train_stage

    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    cfg = UMFConfig.load_yaml(plan)
    launch = Launch(accelerator="gpu" if torch.cuda.is_available() else "cpu", progress=False)
    t0 = time.time()
    res = train_stage(stage, CORPUS, run, cfg, launch, resume=True)
    print(f"== {stage}: {time.time() - t0:.1f} s in all; {res}", flush=True)


def parent(budget: float, overrides: list[str], new_vae: bool, vae_only: bool = False) -> None:
    from umf.config import UMFConfig, family_config, set_option
    from umf.train.run import check_run_config, export_model

    t0 = time.time()
    run = RUNS / "flows"
    if new_vae:
        cfg = family_config("small")
    else:
        (run / "vae").mkdir(parents=True, exist_ok=True)
        if not (run / "vae" / "best").exists():
            shutil.copytree(MODEL, run / "vae" / "best")
        cfg = UMFConfig.load_yaml(MODEL / "config.json")
    for o in overrides:
        cfg = set_option(cfg, o)
    check_run_config(cfg)
    run.mkdir(parents=True, exist_ok=True)
    cfg.save_yaml(run / "plan.yaml")
    OUT.mkdir(parents=True, exist_ok=True)
    finished = run / "vae" / "finished"  # the VAE options, written once a VAE child exits cleanly
    vae_opts = json.dumps(dataclasses.asdict(cfg.vae), sort_keys=True)
    if new_vae and finished.exists() and finished.read_text() != vae_opts:
        raise SystemExit(f"{finished}: a VAE trained with other vae.* options is there; "
                         "remove it or use another RUNS")  # fmt: skip
    if new_vae and not finished.exists():
        vae_cfg = set_option(cfg, f"train_vae.num_workers={os.environ.get('VAE_WORKERS', '12')}")
        (run / "vae-cfg").mkdir(exist_ok=True)
        vae_cfg.save_yaml(run / "vae-cfg" / "plan.yaml")
        with open(OUT / "vae.log", "w") as log:
            p = subprocess.Popen([sys.executable, __file__, "child", "vae", str(run),
                                  str(run / "vae-cfg" / "plan.yaml")],
                                 stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
            rc = wait_until(p, t0 + budget)
        if (run / "vae" / "metrics.csv").exists():
            shutil.copy(run / "vae" / "metrics.csv", OUT / "vae-metrics.csv")
        if rc != 0:  # the flows need a finished VAE: a stopped or failed one ends the run
            raise SystemExit(f"VAE training stopped (exit {rc}, budget {budget:.0f} s); "
                             f"see {OUT / 'vae.log'}")  # fmt: skip
        finished.write_text(vae_opts)
        print(f"VAE done at {time.time() - t0:.0f} s", flush=True)
    if vae_only:
        for f in (run / "vae" / "best").iterdir():  # the VAE comes back even if the node goes
            if f.suffix in (".json", ".safetensors"):  # not the optimiser state
                shutil.copy(f, OUT / f"vae-best-{f.name}")
        print(f"DONE (VAE only) {time.time() - t0:.0f} s", flush=True)
        return
    procs = {}
    for stage, workers in (("pflow", "PFLOW_WORKERS"), ("sflow", "SFLOW_WORKERS")):
        w = os.environ.get(workers, "8")
        stage_cfg = set_option(cfg, f"train_{stage}.num_workers={w}")
        stage_run = run / f"{stage}-cfg"
        stage_run.mkdir(exist_ok=True)
        stage_cfg.save_yaml(stage_run / "plan.yaml")
        log = open(OUT / f"{stage}.log", "w")  # open as long as the child runs
        procs[stage] = subprocess.Popen(
            [sys.executable, __file__, "child", stage, str(run), str(stage_run / "plan.yaml")],
            stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
    codes = {stage: wait_until(p, t0 + budget) for stage, p in procs.items()}
    print(codes, f"{time.time() - t0:.0f} s", flush=True)
    for stage in ("pflow", "sflow"):  # each stage's best weights, whatever happened to the other
        best = run / stage / "best" / f"{stage}.safetensors"
        if best.exists():
            shutil.copy(best, OUT / f"best-{stage}.safetensors")
    model = export_model(run, RUNS / "model")
    for f in sorted(model.iterdir()):
        shutil.copy(f, OUT / f.name)
    for stage in ("pflow", "sflow"):
        if (run / stage / "metrics.csv").exists():
            shutil.copy(run / stage / "metrics.csv", OUT / f"{stage}-metrics.csv")
    shutil.copy(run / "plan.yaml", OUT / "plan.yaml")
    print(f"DONE {time.time() - t0:.0f} s", flush=True)
    failed = {s: c for s, c in codes.items() if c not in (0, STOPPED)}
    if failed:  # exported from the best checkpoints written before the failure
        raise SystemExit(f"stage(s) failed: {failed}; see their logs in {OUT}")


STOPPED = -15  # a stage stopped at the budget (SIGTERM): its best checkpoint is kept


def wait_until(proc: subprocess.Popen, deadline: float) -> int:
    """Wait for ``proc`` until ``deadline`` (time.time()); then stop it (SIGTERM, then
    SIGKILL after 30 s). Returns its exit code."""
    while proc.poll() is None and time.time() < deadline:
        time.sleep(2)
    if proc.poll() is None:
        print(f"budget reached: stopping {proc.args[3]}", flush=True)
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


if __name__ == "__main__":
    if sys.argv[1] == "child":
        child(sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]))
    else:
        args = sys.argv[2:]
        sets = [args[i + 1] for i in range(len(args) - 1) if args[i] == "--set"]
        parent(float(sys.argv[1]), sets, new_vae="--vae" in args or "--vae-only" in args,
               vae_only="--vae-only" in args)  # fmt: skip
