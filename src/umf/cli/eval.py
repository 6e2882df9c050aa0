"""`umf eval`: evaluate a model (and variants) against real test data into one report."""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

from umf.errors import UMFError
from umf.validation import check_device, check_out_dir

DEFAULT_CORPUS = Path("out/corpus")


def resolve_corpus(corpus: Path | None) -> Path:
    """The given corpus, else ``out/corpus``; a missing default says how to make one."""
    if corpus is not None:
        return corpus
    if not DEFAULT_CORPUS.is_dir():
        raise UMFError(
            f"no corpus at {DEFAULT_CORPUS}: run `make corpus` (or `umf data prepare --bandai "
            f"DIR --out {DEFAULT_CORPUS}`) or pass --corpus DIR"
        )
    return DEFAULT_CORPUS


def resolve_evaluator(evaluator: Path | None) -> Path | None:
    """The given evaluator, else the bundled one when this install has it."""
    from umf.eval.plan import default_evaluator_dir

    if evaluator is not None:
        return evaluator
    bundled = default_evaluator_dir()
    return bundled if (bundled / "interaction").is_dir() else None


def command_line(options: list[tuple[str, object]]) -> str:
    """The command as it was effectively given (options left at their defaults omitted)."""
    parts = ["umf", "eval"]
    for flag, value in options:
        if value is True:
            parts.append(flag)
        elif isinstance(value, list):
            for v in value:
                parts += [flag, str(v)]
        elif value is not None and value is not False:
            parts += [flag, str(value)]
    return shlex.join(parts)


def evaluate(
    checkpoint: Path = typer.Option(..., "--checkpoint", help="Model directory to evaluate."),
    evaluator: Path | None = typer.Option(
        None, "--evaluator",
        help="Evaluator: a run from `umf train evaluator` (RUN/evaluator/KIND), a directory "
        "with interaction/ and single/, or one checkpoint. Default: the bundled one, if any.",
    ),
    corpus: Path | None = typer.Option(None, "--corpus", help="Corpus (default out/corpus)."),
    out: Path | None = typer.Option(None, "--out", help="Report directory (results/<model>)."),
    quick: bool = typer.Option(
        False, "--quick", help="2 replications, small MModality and accumulation: minutes."
    ),
    replications: int | None = typer.Option(None, "--replications", help="Protocol repeats."),
    mm_prompts: int | None = typer.Option(
        None, "--mm-prompts", help="MModality prompts (100; 0 skips it)."
    ),
    mm_samples: int | None = typer.Option(None, "--mm-samples", help="Samples per prompt (30)."),
    variant: list[str] = typer.Option(
        [], "--variant",
        help="Also evaluate NAME=MODEL_DIR[:pflow_steps=A,B][:sflow_steps=S][:guidance=G] "
        "(repeatable): an ablation, or the same model at other sampling settings.",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of every draw and generation."),
    batch: int = typer.Option(64, "--batch", help="Prompts per pipeline call."),
    length_step: int | None = typer.Option(
        None, "--length-step",
        help="Generate at lengths rounded up to multiples of this many frames, then cut back "
        "(fewer pipeline calls). Default 1 (exact); 15 with --quick.",
    ),
    split: str = typer.Option(
        "test", "--split",
        help="test (the report) or val (to choose sampling settings or checkpoints: its "
        "pairs, no groups).",
    ),
    device: str = typer.Option("auto", "--device", help="auto, cpu or cuda[:i]."),
    progress: bool = typer.Option(True, help="Show progress bars."),
) -> None:  # fmt: skip
    """Score a model (and variants) on the test split (or val); write report.md, metrics.json,
    PNGs."""
    from umf.eval.plan import make_plan, model_label, parse_variant
    from umf.eval.report import EvalRequest, run_eval

    plan = make_plan(quick, replications, mm_prompts, mm_samples, seed, batch, length_step, split)
    variants = [parse_variant(v) for v in variant]
    command = command_line([
        ("--checkpoint", checkpoint), ("--evaluator", evaluator), ("--corpus", corpus),
        ("--out", out), ("--quick", quick), ("--replications", replications),
        ("--mm-prompts", mm_prompts), ("--mm-samples", mm_samples), ("--variant", variant),
        ("--seed", seed or None), ("--batch", batch if batch != 64 else None),
        ("--length-step", length_step), ("--split", split if split != "test" else None),
        ("--device", device if device != "auto" else None),
    ])  # fmt: skip
    device = check_device(device)
    out = check_out_dir(out or Path("results") / model_label(checkpoint))
    req = EvalRequest(
        checkpoint=checkpoint,
        corpus=resolve_corpus(corpus),
        out=out,
        evaluator=resolve_evaluator(evaluator),
        variants=variants,
        plan=plan,
        device=device,
        progress=progress,
        command=command,
    )
    report = run_eval(req, log=typer.echo)
    typer.echo(f"report written to {report}")
