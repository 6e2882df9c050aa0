"""`umf generate` and `umf react`: text + number of people -> files people can open."""

from __future__ import annotations

import re
from pathlib import Path

import typer

from umf.errors import UMFError

FORMATS = ("npz", "gif", "mp4", "bvh", "glb")


def _slug(text: str, limit: int = 40) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit] or "scene"


def parse_formats(formats: str) -> list[str]:
    wanted = [f.strip().lower() for f in formats.split(",") if f.strip()]
    bad = [f for f in wanted if f not in FORMATS]
    if bad or not wanted:
        raise UMFError(f"unknown format {','.join(bad) or formats!r}; choose from {FORMATS}")
    return wanted


def parse_steps(steps: str | None) -> list[int] | None:
    if not steps:
        return None
    try:
        values = [int(s) for s in steps.split(",")]
    except ValueError as exc:
        raise UMFError(f"--steps takes integers like 45,5, got {steps!r}") from exc
    if any(v < 1 for v in values):
        raise UMFError(f"--steps must be positive, got {steps!r}")
    return values


def load_pipeline(model: Path | None):
    """The bundled model, or the model directory the user named (one-line errors)."""
    from umf.pipeline import UMFPipeline, default_model_dir

    if model is None and not default_model_dir().exists():
        raise UMFError("no bundled model in this install; pass --model DIR (see umf train)")
    return UMFPipeline.from_pretrained(model)


def write_scene(scene, stem: Path, wanted: list[str]) -> list[Path]:
    """Every requested file of one scene, named ``stem.*`` (BVH: one per person)."""
    written: list[Path] = []
    if "npz" in wanted:
        written.append(scene.save_npz(stem.with_suffix(".npz")))
    if "bvh" in wanted:
        written += scene.save_bvh(f"{stem}-p{{i}}.bvh")
    if "glb" in wanted:
        written.append(scene.save_glb(stem.with_suffix(".glb")))
    for ext in ("gif", "mp4"):
        if ext in wanted:
            written.append(scene.render(stem.with_suffix(f".{ext}"), progress=False))
    return written


def _read_prompts(prompt: str | None, prompts: Path | None) -> list[str]:
    texts = [prompt] if prompt is not None else []
    if prompts is not None:
        try:
            lines = prompts.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise UMFError(f"cannot read prompts file {prompts}") from exc
        texts += [t.strip() for t in lines if t.strip() and not t.lstrip().startswith("#")]
    if not texts:
        raise UMFError("give a prompt or --prompts FILE")
    if any(not t.strip() for t in texts):
        raise UMFError("the prompt is empty")
    return texts


def _check_batch(batch: int) -> None:
    if not 1 <= batch <= 256:
        raise UMFError(f"--batch must be between 1 and 256, got {batch}")


def generate(
    prompt: str | None = typer.Argument(None, help="What the people do."),
    people: int = typer.Option(2, "--people", "-n", help="Number of people (1-16)."),
    seconds: float = typer.Option(4.0, help="Duration (0.5-10 s)."),
    seed: int = typer.Option(0, help="Random seed."),
    guidance: float | None = typer.Option(None, help="Classifier-free guidance (model default)."),
    steps: str | None = typer.Option(None, help="P-Flow steps per stage, coarse to fine: 45,5."),
    sflow_steps: int | None = typer.Option(None, help="S-Flow steps per person."),
    batch: int = typer.Option(1, "--batch", "-b", help="Scenes per prompt, sampled together."),
    prompts: Path | None = typer.Option(None, help="Text file: one prompt per line."),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/generate"), help="Output directory."),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
    view: bool = typer.Option(False, "--view", help="Then play the scenes in the 3-D page."),
    port: int = typer.Option(8000, help="Port of the --view page (0: any free port)."),
) -> None:
    """Generate synchronized motion for N people from text."""
    wanted = parse_formats(formats)
    texts = _read_prompts(prompt, prompts)
    step_list = parse_steps(steps)
    _check_batch(batch)
    if view:  # before the work: say at once when the page cannot be shown
        from umf.serve.server import find_three, three_missing_message

        if find_three() is None:
            raise UMFError(three_missing_message())
    pipe = load_pipeline(model)
    jobs = [(k, text, j) for k, text in enumerate(texts) for j in range(batch)]
    scenes = pipe([text for _, text, _ in jobs], num_people=people, seconds=seconds, seed=seed,
                  guidance=guidance, pflow_steps=step_list, sflow_steps=sflow_steps)  # fmt: skip
    for (k, text, j), scene in zip(jobs, scenes, strict=True):
        stem = out / f"{k:02d}-{_slug(text)}" if batch == 1 else out / f"{k:02d}-{_slug(text)}-{j}"
        for path in write_scene(scene, stem, wanted):
            typer.echo(f"wrote {path}")
    if view:
        from umf.cli.serve import view_scenes

        params = {"seed": seed, "guidance": guidance, "steps": step_list}
        view_scenes(scenes, pipe, params | {"sflow_steps": sflow_steps}, port)


def react(
    prompt: str = typer.Argument(..., help="What everybody does, person 1 included."),
    actor: Path = typer.Option(..., help="Person 1's motion: a .bvh or umf .npz file."),
    people: int = typer.Option(2, "--people", "-n", help="Number of people, actor included."),
    actor_person: int = typer.Option(1, help="Which person of a multi-person .npz to use."),
    start: float = typer.Option(0.0, help="Where in the actor file to start (s)."),
    seconds: float | None = typer.Option(None, help="How much of it to use (default: all)."),
    seed: int = typer.Option(0, help="Random seed."),
    guidance: float | None = typer.Option(None, help="Classifier-free guidance (model default)."),
    sflow_steps: int | None = typer.Option(None, help="S-Flow steps per person."),
    batch: int = typer.Option(1, "--batch", "-b", help="Scenes to sample around the actor."),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/react"), help="Output directory."),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
) -> None:
    """Your own motion as person 1; the model generates the others around it."""
    from umf.data.motion_file import FPS, load_motion

    wanted = parse_formats(formats)
    if not prompt.strip():
        raise UMFError("the prompt is empty")
    _check_batch(batch)
    if people < 2:
        raise UMFError(f"--people counts the actor, so it must be at least 2, got {people}")
    motion = load_motion(actor)
    if not 1 <= actor_person <= motion.num_people:
        raise UMFError(f"{actor}: has {motion.num_people} people, no person {actor_person}")
    joints = motion.joints[actor_person - 1]
    first = round(start * FPS)
    if not 0 <= first < joints.shape[0]:
        raise UMFError(
            f"--start {start} s is outside the actor motion ({joints.shape[0] / FPS:.1f} s)"
        )
    pipe = load_pipeline(model)
    most = pipe.config.vae.max_frames + 1
    count = most if seconds is None else round(seconds * FPS) + 1
    joints = joints[first : first + count]
    if seconds is None and motion.num_frames - first > most:
        end = start + most / FPS
        typer.echo(f"note: the actor motion is longer than {most / FPS:.1f} s; using "
                   f"{start:.1f}-{end:.1f} s (--start/--seconds choose)")  # fmt: skip
    scenes = pipe([prompt] * batch, num_people=people, seed=seed, guidance=guidance,
                  sflow_steps=sflow_steps, actor=joints)  # fmt: skip
    for j, scene in enumerate(scenes):
        stem = out / (f"react-{_slug(prompt)}" + (f"-{j}" if batch > 1 else ""))
        for path in write_scene(scene, stem, wanted):
            typer.echo(f"wrote {path}")
