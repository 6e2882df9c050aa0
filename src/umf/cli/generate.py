"""`umf generate`: text + number of people -> files people can open."""

from __future__ import annotations

import re
from pathlib import Path

import typer

from umf.errors import UMFError

FORMATS = ("npz", "gif", "mp4", "bvh")


def _slug(text: str, limit: int = 40) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit] or "scene"


def generate(
    prompt: str | None = typer.Argument(None, help="What the people do."),
    people: int = typer.Option(2, "--people", "-n", help="Number of people (1-16)."),
    seconds: float = typer.Option(4.0, help="Duration (0.5-10 s)."),
    seed: int = typer.Option(0, help="Random seed."),
    guidance: float | None = typer.Option(None, help="Classifier-free guidance (model default)."),
    steps: str | None = typer.Option(None, help="P-Flow steps per stage, coarse to fine: 45,5."),
    sflow_steps: int | None = typer.Option(None, help="S-Flow steps per person."),
    prompts: Path | None = typer.Option(None, help="Text file: one prompt per line."),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/generate"), help="Output directory."),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
) -> None:
    """Generate synchronized motion for N people from text."""
    from umf.pipeline import UMFPipeline, default_model_dir

    wanted = [f.strip().lower() for f in formats.split(",") if f.strip()]
    bad = [f for f in wanted if f not in FORMATS]
    if bad or not wanted:
        raise UMFError(f"unknown format {','.join(bad) or formats!r}; choose from {FORMATS}")
    texts = [prompt] if prompt is not None else []
    if prompts is not None:
        try:
            texts += [t.strip() for t in prompts.read_text().splitlines() if t.strip()]
        except OSError as exc:
            raise UMFError(f"cannot read prompts file {prompts}") from exc
    if not texts:
        raise UMFError("give a prompt or --prompts FILE")
    step_list = None
    if steps:
        try:
            step_list = [int(s) for s in steps.split(",")]
        except ValueError as exc:
            raise UMFError(f"--steps takes integers like 45,5, got {steps!r}") from exc
    if model is None and not default_model_dir().exists():
        raise UMFError("no bundled model in this install yet; pass --model DIR (umf train)")
    pipe = UMFPipeline.from_pretrained(model)
    scenes = pipe(texts, num_people=people, seconds=seconds, seed=seed, guidance=guidance,
                  pflow_steps=step_list, sflow_steps=sflow_steps)  # fmt: skip
    for k, scene in enumerate(scenes):
        stem = out / f"{k:02d}-{_slug(scene.text)}"
        written: list[Path] = []
        if "npz" in wanted:
            written.append(scene.save_npz(stem.with_suffix(".npz")))
        if "bvh" in wanted:
            written += scene.save_bvh(f"{stem}-p{{i}}.bvh")
        for ext in ("gif", "mp4"):
            if ext in wanted:
                written.append(scene.render(stem.with_suffix(f".{ext}"), progress=False))
        for path in written:
            typer.echo(f"wrote {path}")
