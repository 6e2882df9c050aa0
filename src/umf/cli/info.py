"""`umf info [MODEL]`: what a model knows (actions, styles, relations) and how it was made."""

from __future__ import annotations

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
    from umf.cli.loading import load_pipeline
    from umf.person_prompts import takes_person_prompts
    from umf.pipeline import default_model_dir
    from umf.validation import check_text

    prompt = [check_text(p) for p in prompt]
    path = model if model is not None else default_model_dir()
    if not (path / "config.json").exists():
        raise UMFError(f"{path}: not a model directory (no config.json)")
    pipe = load_pipeline(model)  # a damaged model is said so here, not described
    config = pipe.config
    vocab = pipe.vocabulary
    typer.echo(f"model: {pipe.name} ({path})")
    typer.echo(
        "per-person prompts (--person): " + ("yes" if takes_person_prompts(config) else "no")
    )
    if vocab is None:
        what = ("this model carries no vocabulary (trained before umf 0.2, or exported without "
                "--corpus): `umf train vocabulary` adds one")  # fmt: skip
        if prompt:
            raise UMFError(f"cannot score --prompt: {what}")
        typer.echo(what)
        return
    typer.echo(f"actions ({len(vocab.actions)}): {', '.join(vocab.actions)}")
    typer.echo(f"styles ({len(vocab.styles)}): {', '.join(vocab.styles)}")
    typer.echo(f"multi-person relations ({len(vocab.relations)}): {', '.join(vocab.relations)}")
    if vocab.groups:
        typer.echo(f"group relations, 3 or more people composed at sampling ({len(vocab.groups)}):"
                   f" {', '.join(vocab.groups)}")  # fmt: skip
    typer.echo(f"known captions: {len(vocab.phrases)}; a prompt is known when its coverage "
               f"(cosine to the nearest one) is at least {vocab.threshold:.3f}")  # fmt: skip
    touching = sorted(vocab.contact)
    if touching:
        take = config.sflow.warm_take
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
        for p, cov in zip(prompt, pipe.coverage(list(prompt)), strict=True):
            verdict = "known" if cov["known"] else "NOT known"
            touch = "; worded like a real take whose people touch" if "contact" in cov else ""
            typer.echo(
                f"{p!r}: {verdict} (coverage {cov['score']:.3f}{touch}); nearest: "
                + "; ".join(cov["nearest"])
            )
