"""`umf info [MODEL]`: what a model knows (actions, styles, relations) and how it was made."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from umf.errors import UMFError


def info(
    model: Path | None = typer.Argument(None, help="Model directory (default: bundled)."),
    phrases: bool = typer.Option(False, help="Also list every trained caption."),
    prompt: list[str] = typer.Option([], "--prompt", help="Score a prompt's coverage "
                                     "(repeatable): known or not, and its nearest captions."),
) -> None:  # fmt: skip
    """List the model's actions, styles and multi-person relations; score prompts."""
    from umf.cli.loading import peek_config
    from umf.coverage import Vocabulary
    from umf.person_prompts import takes_person_prompts
    from umf.pipeline import default_model_dir

    path = model if model is not None else default_model_dir()
    if not (path / "config.json").exists():
        raise UMFError(f"{path}: not a model directory (no config.json)")
    try:
        fmt = (
            json.loads((path / "format.json").read_text())
            if (path / "format.json").exists()
            else {}
        )
    except (OSError, ValueError):
        fmt = {}
    vocab = Vocabulary.load(path)
    typer.echo(f"model: {fmt.get('name') or path.name} ({path})")
    config = peek_config(path)
    own = config is not None and takes_person_prompts(config)
    typer.echo("per-person prompts (--person): " + ("yes" if own else "no"))
    if vocab is None:
        typer.echo("this model carries no vocabulary (trained before umf 0.2, or exported "
                   "without --corpus): `umf train vocabulary` adds one")  # fmt: skip
        return
    typer.echo(f"actions ({len(vocab.actions)}): {', '.join(vocab.actions)}")
    typer.echo(f"styles ({len(vocab.styles)}): {', '.join(vocab.styles)}")
    typer.echo(f"multi-person relations ({len(vocab.relations)}): {', '.join(vocab.relations)}")
    typer.echo(f"trained captions: {len(vocab.phrases)}; a prompt is known when its coverage "
               f"(cosine to the nearest one) is at least {vocab.threshold:.3f}")  # fmt: skip
    touching = sorted(vocab.contact)
    if touching:
        take = config.sflow.warm_take if config is not None else 0.0
        how = "the clean-up lets such a couple touch"
        if take:
            how = f"a couple worded like one is finished from one of them, warm_take {take:g}"
        more = " ..." if len(touching) > 3 else ""
        typer.echo(f"people who touch ({len(touching)} captions of real takes; {how}): "
                   + "; ".join(touching[:3]) + more)  # fmt: skip
    if phrases:
        for p in vocab.phrases:
            typer.echo(f"  {p}")
    if prompt:
        from umf.pipeline import UMFPipeline

        pipe = UMFPipeline.from_pretrained(model)
        for p, cov in zip(prompt, pipe.coverage(list(prompt)), strict=True):
            verdict = "known" if cov["known"] else "NOT known"
            touch = "; worded like a real take whose people touch" if "contact" in cov else ""
            typer.echo(
                f"{p!r}: {verdict} (coverage {cov['score']:.3f}{touch}); nearest: "
                + "; ".join(cov["nearest"])
            )
