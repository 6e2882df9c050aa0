"""`umf train ...`: the three stages, all of them in order, the model export, the evaluators."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(help="Train UMF: vae, pflow, sflow, or all three; export a model.",
                  no_args_is_help=True)  # fmt: skip

CORPUS = typer.Option(..., "--corpus", help="A corpus from `umf data prepare`.")
RUN = typer.Option(..., "--out", help="Run directory (one sub-directory per stage).")
FAMILY = typer.Option(None, help="Config family: small (CPU, default) or paper (GPU).")
CONFIG = typer.Option(None, "--config", help="YAML config (family + overrides).")
SET = typer.Option([], "--set", help="Override one option, e.g. --set pflow.num_stages=1.")
STEPS = typer.Option(None, "--max-steps", help="Override the stage's max_steps.")
ACCEL = typer.Option("cpu", help="cpu, gpu or auto (Lightning Fabric).")
DEVICES = typer.Option("1", help="Devices per node (number or 'auto').")
NODES = typer.Option(1, "--num-nodes", help="Number of nodes.")
STRATEGY = typer.Option("auto", help="auto or ddp.")
PRECISION = typer.Option("32-true", help="32-true, bf16-mixed, 16-mixed.")
RESUME = typer.Option(False, "--resume", help="Continue a killed run from its last checkpoint.")
PROGRESS = typer.Option(True, help="Show progress bars.")
TB = typer.Option(False, "--tensorboard", help="Also log to TensorBoard (if installed).")
INIT = typer.Option(None, "--init", help="Fine-tune: start from this model directory's weights "
                    "for the stage (and use its VAE if the run has none).")  # fmt: skip


def _launch(accelerator, devices, num_nodes, strategy, precision, progress, tensorboard):
    from umf.train.run import Launch

    dev: int | str = int(devices) if str(devices).isdigit() else devices
    return Launch(accelerator, dev, num_nodes, strategy, precision, progress, tensorboard)


def _run(stages, corpus, out, family, config, set_, max_steps, launch, resume,
         init: Path | None = None) -> None:  # fmt: skip
    from umf.errors import UMFError
    from umf.train.run import resolve_config, train_stage
    from umf.validation import check_out_dir

    check_out_dir(Path(out))
    fresh = not (Path(out) / "config.yaml").exists()
    if init is not None and family is None and config is None and fresh:
        config = Path(init) / "config.json"  # fine-tuning keeps the model's configuration
        if not config.exists():
            raise UMFError(f"{init}: not a model directory (no config.json)")
    cfg = resolve_config(out, family, config, set_)
    for stage in stages:
        summary = train_stage(stage, corpus, out, cfg, launch, resume=resume,
                              max_steps=max_steps, init=init, log=typer.echo)  # fmt: skip
        typer.echo(
            f"{stage}: {summary.get('steps')} steps in {summary.get('seconds', 0):.0f} s "
            f"({summary.get('seconds_per_step', 0):.3f} s/step); best val "
            f"{summary.get('best_val')}; checkpoints in {out / stage}"
        )


def _stage_command(stage: str):
    def command(
        corpus: Path = CORPUS, out: Path = RUN, family: str | None = FAMILY,
        config: Path | None = CONFIG, set_: list[str] = SET, max_steps: int | None = STEPS,
        accelerator: str = ACCEL, devices: str = DEVICES, num_nodes: int = NODES,
        strategy: str = STRATEGY, precision: str = PRECISION, resume: bool = RESUME,
        progress: bool = PROGRESS, tensorboard: bool = TB, init: Path | None = INIT,
    ) -> None:  # fmt: skip
        launch = _launch(accelerator, devices, num_nodes, strategy, precision, progress,
                         tensorboard)  # fmt: skip
        _run([stage], corpus, out, family, config, set_, max_steps, launch, resume, init)

    command.__doc__ = {
        "vae": "Train the motion VAE (single-person crops and scenes).",
        "pflow": "Train P-Flow on the run's frozen VAE latents (needs `train vae`).",
        "sflow": "Train S-Flow on scenes, VAE frozen (needs `train vae`).",
    }[stage]
    return command


for _stage in ("vae", "pflow", "sflow"):
    app.command(_stage)(_stage_command(_stage))


@app.command("all")
def all_stages(
    corpus: Path = CORPUS, out: Path = RUN, family: str | None = FAMILY,
    config: Path | None = CONFIG, set_: list[str] = SET, max_steps: int | None = STEPS,
    accelerator: str = ACCEL, devices: str = DEVICES, num_nodes: int = NODES,
    strategy: str = STRATEGY, precision: str = PRECISION, resume: bool = RESUME,
    progress: bool = PROGRESS, tensorboard: bool = TB,
    fp16: bool = typer.Option(True, help="Export weights in fp16."),
) -> None:  # fmt: skip
    """Train vae, pflow and sflow in order, then export RUN/model."""
    from umf.train.run import export_model

    launch = _launch(accelerator, devices, num_nodes, strategy, precision, progress, tensorboard)
    _run(["vae", "pflow", "sflow"], corpus, out, family, config, set_, max_steps, launch, resume)
    path = export_model(out, out / "model", fp16=fp16)
    typer.echo(f"model written to {path}")


@app.command("finetune")
def finetune_command(
    from_: Path = typer.Option(..., "--from", help="The model to start from (a model "
                               "directory; 'bundled' for the bundled model)."),
    corpus: Path = CORPUS, out: Path = RUN, set_: list[str] = SET,
    stages: str = typer.Option("vae,pflow,sflow", help="Stages to fine-tune (the others "
                               "are the model's)."),
    accelerator: str = ACCEL, devices: str = DEVICES, num_nodes: int = NODES,
    strategy: str = STRATEGY, precision: str = PRECISION, resume: bool = RESUME,
    progress: bool = PROGRESS, tensorboard: bool = TB,
) -> None:  # fmt: skip
    """Teach a released model a new library: fine-tune its stages on a corpus that holds
    the new clips beside the model's own data (replay), then export RUN/model."""
    from umf.cli.loading import load_pipeline
    from umf.pipeline import default_model_dir
    from umf.train.loop import check_launch
    from umf.train.run import finetune
    from umf.validation import check_out_dir

    model = default_model_dir() if str(from_) == "bundled" else from_
    launch = _launch(accelerator, devices, num_nodes, strategy, precision, progress, tensorboard)
    # before anything is written: a missing pflow.safetensors was found after the VAE trained
    check_out_dir(out)
    load_pipeline(model)  # every module the run starts from or keeps loads
    check_launch(accelerator, launch.devices, num_nodes, strategy, precision)
    path = finetune(
        model,
        corpus,
        out,
        set_,
        launch,
        resume=resume,
        stages=[s.strip() for s in stages.split(",") if s.strip()],
        log=typer.echo,
    )
    typer.echo(f"model written to {path}")


@app.command("vocabulary")
def vocabulary(
    model: Path = typer.Option(..., "--model", help="Model directory to add it to."),
    corpus: Path = CORPUS,
    threshold: float | None = typer.Option(None, help="Coverage below which a prompt is "
                                           "unknown (default: the calibrated one)."),
) -> None:  # fmt: skip
    """Write the model's training vocabulary (captions, actions, styles, relations, group
    relations and their text embeddings) from the corpus it was trained on, for coverage
    warnings."""
    from umf.coverage import THRESHOLD
    from umf.train.run import write_vocabulary
    from umf.validation import check_float

    t = THRESHOLD if threshold is None else check_float("--threshold", threshold, -1.0, 1.0)
    vocab = write_vocabulary(model, corpus, t)
    typer.echo(f"vocabulary of {len(vocab.phrases)} captions, {len(vocab.actions)} actions, "
               f"{len(vocab.groups)} group relations written to {model}")  # fmt: skip


@app.command("reactions")
def reactions(
    model: Path = typer.Option(..., "--model", help="Model directory to add them to."),
    corpus: Path = CORPUS,
    per_length: int = typer.Option(1024, help="At most this many reactions per length."),
    progress: bool = PROGRESS,
) -> None:
    """Write the model's bank of real reactions (people 2..N of the corpus's train scenes,
    encoded by the model's VAE) for sflow.warm_proposal 'retrieved'."""
    from umf.train.reactions import write_reactions
    from umf.validation import check_int

    check_int("--per-length", per_length, 1, 1_000_000)
    bank = write_reactions(model, corpus, per_length, progress, log=typer.echo)
    typer.echo(f"{sum(len(z) for z in bank.latents.values())} reactions of "
               f"{len(bank.latents)} lengths written to {model}")  # fmt: skip


@app.command("evaluator")
def evaluator(
    corpus: Path = CORPUS, out: Path = RUN, family: str | None = FAMILY,
    config: Path | None = CONFIG, set_: list[str] = SET, max_steps: int | None = STEPS,
    kind: list[str] = typer.Option(["interaction", "single"], help="interaction and/or single."),
    accelerator: str = ACCEL, devices: str = DEVICES, num_nodes: int = NODES,
    strategy: str = STRATEGY, precision: str = PRECISION, resume: bool = RESUME,
    progress: bool = PROGRESS, tensorboard: bool = TB,
) -> None:  # fmt: skip
    """Train the contrastive text-motion evaluators (two-person and single) into RUN/evaluator."""
    from umf.train.evaluator_stage import train_evaluators
    from umf.train.run import resolve_config

    launch = _launch(accelerator, devices, num_nodes, strategy, precision, progress, tensorboard)
    cfg = resolve_config(out, family, config, set_)
    summaries = train_evaluators(corpus, out, cfg, launch, kinds=kind, resume=resume,
                                 max_steps=max_steps, log=typer.echo)  # fmt: skip
    for name, s in summaries.items():
        val = s.get("val") or {}
        tops = " / ".join(f"{val.get(f'r_precision_top{k}', float('nan')):.3f}" for k in (1, 2, 3))
        typer.echo(
            f"evaluator {name}: {s.get('steps')} steps in {s.get('seconds', 0):.0f} s; "
            f"val R-precision top-1/2/3 {tops}; checkpoints in {out / 'evaluator' / name}"
        )


@app.command()
def export(
    run: Path = typer.Option(..., "--run", help="A run directory (all three stages, or --base)."),
    out: Path = typer.Option(..., "--out", help="Model directory to write."),
    fp16: bool = typer.Option(True, help="Store weights in fp16."),
    base: Path | None = typer.Option(None, "--base", help="Model directory supplying the "
                                     "stages the run did not train (after --init)."),
) -> None:  # fmt: skip
    """Collect a run's best checkpoints into one model directory."""
    from umf.train.run import export_model

    typer.echo(f"model written to {export_model(run, out, fp16=fp16, base=base, log=typer.echo)}")
