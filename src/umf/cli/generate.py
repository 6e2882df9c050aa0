"""`umf generate` and `umf react`: text + number of people -> files people can open."""

from __future__ import annotations

import re
from pathlib import Path

import typer

from umf.cli.loading import load_pipeline, peek_config
from umf.errors import UMFError
from umf.exports import FORMATS, check_formats
from umf.person_prompts import check_person_prompts
from umf.validation import (
    MAX_SECONDS,
    MIN_SECONDS,
    check_actor,
    check_batch,
    check_device,
    check_float,
    check_for_model,
    check_int,
    check_out_dir,
    check_port,
    check_request,
    check_targets,
    chunk_size,
    chunks,
)
from umf.writer import clean_stale, scene_targets, write_scene_files

SFLOW_STEPS_HELP = (
    "S-Flow steps per added person, 1-200 (default: the model's; bundled: 4 for two people, "
    "else 10)."
)


def _slug(text: str, limit: int = 40) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:limit] or "scene"


def parse_formats(formats: str) -> list[str]:
    return check_formats(formats)


def parse_steps(steps: str | None) -> list[int] | None:
    """``--steps 45,5`` as integers; their bounds are checked by :func:`check_request`."""
    if steps is None:
        return None
    try:
        return [int(s) for s in steps.split(",")]
    except ValueError as exc:
        raise UMFError(f"--steps takes integers like 45,5, got {steps!r}") from exc


PERSON_HELP = (
    "What person K does, beside the scene prompt: the K-th --person is person K (repeat it; "
    "fewer than the people is fine, the others follow the scene prompt alone; '-' skips one)."
)


def person_list(person: list[str]) -> list[str | None] | None:
    """``--person`` values, '-' (or an empty one) for a person left to the scene prompt."""
    own = [None if p.strip() in ("", "-") else p for p in person]
    return own if any(p is not None for p in own) else None


def warn_unknown(pipe, prompts: list[str]) -> None:
    """One warning line on stderr per distinct prompt the model was not trained for."""
    from umf.coverage import warning_line

    seen = list(dict.fromkeys(prompts))
    for prompt, cov in zip(seen, pipe.coverage(seen), strict=True):
        if cov is not None and not cov["known"]:
            typer.echo(warning_line(prompt, cov), err=True)


def write_scene(scene, stem: Path, wanted: list[str]) -> list[Path]:
    """Every requested file of one scene, named ``stem.*`` (BVH: one per person), all
    written together (:mod:`umf.writer`)."""
    return write_scene_files(scene, stem, wanted)


def _stem(out: Path, k: int, text: str, j: int, batch: int) -> Path:
    return out / (f"{k:02d}-{_slug(text)}" + (f"-{j}" if batch > 1 else ""))


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


def generate(
    prompt: str | None = typer.Argument(None, help="What the people do."),
    people: int = typer.Option(2, "--people", "-n", help="Number of people (1-16)."),
    seconds: float = typer.Option(4.0, help="Duration (0.5-10 s)."),
    seed: int = typer.Option(0, help="Random seed (0 to 2^64-1)."),
    guidance: float | None = typer.Option(None, help="CFG scale, 0-20 (model default)."),
    steps: str | None = typer.Option(
        None, help="P-Flow steps per stage, e.g. 45,5 (200 in all; model default, bundled 5,5)."
    ),
    sflow_steps: int | None = typer.Option(None, help=SFLOW_STEPS_HELP),
    batch: int = typer.Option(1, "--batch", "-b", help="Samples per prompt (1-256)."),
    prompts: Path | None = typer.Option(None, help="Text file: one prompt per line."),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/generate"), help="Output directory."),
    anchor: bool = typer.Option(
        True,
        help="Move a gliding body back so planted feet stay put (--no-anchor: the decoded path).",
    ),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
    device: str = typer.Option(
        "cpu",
        "--device",
        help="cpu, cuda[:i] or auto. A seed's scene is the same on every CPU; a GPU draws "
        "other noise (and fits every scene's people at once: faster for --batch).",
    ),
    view: bool = typer.Option(False, "--view", help="Then play the scenes in the 3-D page."),
    port: int = typer.Option(8000, help="Port of the --view page (0: any free port)."),
    person: list[str] = typer.Option([], "--person", help=PERSON_HELP),
) -> None:
    """Generate synchronized motion for N people from text."""
    wanted = parse_formats(formats)
    texts = _read_prompts(prompt, prompts)
    req = check_request(texts, people, seconds, seed, guidance, parse_steps(steps), sflow_steps,
                        person_prompts=person_list(person))  # fmt: skip
    batch = check_batch(batch, len(texts))
    check_out_dir(out)
    device = check_device(device)
    if view:  # before the work: say at once when the page cannot be shown
        from umf.serve.server import find_three, three_missing_message

        check_port(port)
        if find_three() is None:
            raise UMFError(three_missing_message())
    jobs = [(k, text, j) for k, text in enumerate(texts) for j in range(batch)]
    stems = [_stem(out, k, text, j, batch) for k, text, j in jobs]
    check_targets([p for stem in stems for p in scene_targets(stem, wanted, req.num_people)])
    config = peek_config(model)
    if config is not None:
        check_for_model(req, config)
    if config is not None:
        check_person_prompts(config, req.person_prompts)
    pipe = load_pipeline(model).to(device)
    frames = check_for_model(req, pipe.config)
    warn_unknown(pipe, texts + [p for p in req.person_prompts if p is not None])
    clean_stale(out)
    shown = []
    for part in chunks(len(jobs), chunk_size(req.num_people, frames)):
        scenes = pipe([jobs[i][1] for i in part], num_people=req.num_people, seconds=req.seconds,
                      seed=req.seed, guidance=req.guidance, pflow_steps=req.pflow_steps,
                      sflow_steps=req.sflow_steps, anchor=anchor,
                      sample_indices=[jobs[i][2] for i in part],
                      person_prompts=req.person_prompts or None)  # fmt: skip
        for i, scene in zip(part, scenes, strict=True):
            for path in write_scene(scene, stems[i], wanted):
                typer.echo(f"wrote {path}")
        if view:
            shown.extend(scenes)
    if view:
        from umf.cli.serve import view_scenes

        params = {"seed": req.seed, "guidance": req.guidance, "steps": req.pflow_steps,
                  "person_prompts": list(req.person_prompts) or None}  # fmt: skip
        view_scenes(shown, pipe, params | {"sflow_steps": req.sflow_steps}, port)


def react(
    prompt: str = typer.Argument(..., help="What everybody does, person 1 included."),
    actor: Path = typer.Option(..., help="Person 1's motion: a .bvh or umf .npz file."),
    people: int = typer.Option(2, "--people", "-n", help="Number of people, actor included."),
    actor_person: int = typer.Option(1, help="Which person of a multi-person .npz to use."),
    start: float = typer.Option(0.0, help="Where in the actor file to start (s)."),
    seconds: float | None = typer.Option(None, help="How much of it to use (default: all)."),
    seed: int = typer.Option(0, help="Random seed (0 to 2^64-1)."),
    guidance: float | None = typer.Option(None, help="CFG scale, 0-20 (model default)."),
    sflow_steps: int | None = typer.Option(None, help=SFLOW_STEPS_HELP),
    batch: int = typer.Option(1, "--batch", "-b", help="Scenes to sample around the actor."),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/react"), help="Output directory."),
    anchor: bool = typer.Option(
        True,
        help="Move a gliding body back so planted feet stay put (--no-anchor: the decoded path).",
    ),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
    person: list[str] = typer.Option([], "--person", help="What each added person does, "
                                     "beside the prompt: the first --person is person 2 "
                                     "('-' skips one)."),
) -> None:  # fmt: skip
    """Your own motion as person 1; the model generates the others around it."""
    from umf.data.motion_file import FPS, open_motion

    wanted = parse_formats(formats)
    req = check_request(prompt, people, seed=seed, guidance=guidance, sflow_steps=sflow_steps)
    if req.num_people < 2:
        raise UMFError(f"--people counts the actor, so it must be at least 2, got {people}")
    if len(person) > req.num_people - 1:
        raise UMFError(f"{len(person)} --person prompts for {req.num_people - 1} added "
                       f"{'person' if req.num_people == 2 else 'people'}")  # fmt: skip
    asked = person_list(person)
    own = () if asked is None else check_request(
        prompt, req.num_people, person_prompts=[None, *asked]).person_prompts  # fmt: skip
    batch = check_batch(batch, 1)
    start = check_float("--start", start, 0.0, 1e6)
    if seconds is not None:
        seconds = check_float("--seconds", seconds, MIN_SECONDS, MAX_SECONDS)
    check_int("--actor-person", actor_person, 1, 1 << 20)
    check_out_dir(out)
    stems = [
        out / (f"react-{_slug(prompt)}" + (f"-{j}" if batch > 1 else "")) for j in range(batch)
    ]
    check_targets([p for stem in stems for p in scene_targets(stem, wanted, req.num_people)])
    config = peek_config(model)
    if config is not None:
        check_person_prompts(config, own, acting=True)
    most = (config.vae.max_frames if config is not None else 300) + 1
    count = most if seconds is None else round(seconds * FPS) + 1
    first = round(start * FPS)
    motion = open_motion(actor)  # read and checked, not yet resampled or fitted
    if not 1 <= actor_person <= motion.num_people:
        raise UMFError(f"{actor}: has {motion.num_people} people, no person {actor_person}")
    total = motion.frames
    if not 0 <= first < total:
        raise UMFError(f"--start {start} s is outside the actor motion ({total / FPS:.1f} s)")
    if seconds is not None and first + count > total:
        left = (total - 1 - first) / FPS
        raise UMFError(f"--seconds {seconds}: the actor motion has only {left:.1f} s after --start")
    # the window is cut before the resampling and the body fit: a long file costs its window
    joints = motion.scene(first, count).joints[actor_person - 1]
    if config is not None:
        check_actor(joints, FPS, config.vae.max_frames)
    pipe = load_pipeline(model)
    if seconds is None and total - first > most:
        end = start + most / FPS
        typer.echo(f"note: the actor motion is longer than {most / FPS:.1f} s; using "
                   f"{start:.1f}-{end:.1f} s (--start/--seconds choose)")  # fmt: skip
    warn_unknown(pipe, [prompt, *[p for p in own if p is not None]])
    clean_stale(out)
    for part in chunks(batch, chunk_size(req.num_people, joints.shape[0])):
        scenes = pipe([prompt] * len(part), num_people=req.num_people, seed=req.seed,
                      guidance=req.guidance, sflow_steps=req.sflow_steps, actor=joints,
                      anchor=anchor, sample_indices=list(part),
                      person_prompts=list(own) or None)  # fmt: skip
        for j, scene in zip(part, scenes, strict=True):
            for path in write_scene(scene, stems[j], wanted):
                typer.echo(f"wrote {path}")


def reroll(
    scene_file: Path = typer.Argument(..., help="A umf .npz scene of two or more people."),
    person: int = typer.Option(..., "--person", "-p", help="Who to re-roll (1 = the -p1 files)."),
    seed: int = typer.Option(0, help="Random seed for the new person (0 to 2^64-1)."),
    prompt: str | None = typer.Option(None, help="What happens (default: the scene's prompt)."),
    guidance: float | None = typer.Option(None, help="CFG scale, 0-20 (model default)."),
    sflow_steps: int | None = typer.Option(None, help=SFLOW_STEPS_HELP),
    formats: str = typer.Option("npz,gif", "--format", help=f"Any of {','.join(FORMATS)}."),
    out: Path = typer.Option(Path("out/reroll"), help="Output directory."),
    anchor: bool = typer.Option(
        True,
        help="Move a gliding body back so planted feet stay put (--no-anchor: the decoded path).",
    ),
    model: Path | None = typer.Option(None, help="Model directory (default: bundled)."),
    person_prompt: str | None = typer.Option(None, help="What this person does (default: "
                                             "what the scene recorded for them, if anything)."),
) -> None:  # fmt: skip
    """Generate one person of a scene again; everyone else stays exactly as they were."""
    from umf.data.motion_file import FPS, open_motion, open_scene

    wanted = parse_formats(formats)
    check_int("--person", person, 1, 1 << 20)
    check_int("--seed", seed, 0, (1 << 64) - 1)
    if guidance is not None:
        check_float("--guidance", guidance, 0.0, 20.0)
    if sflow_steps is not None:
        check_int("--sflow-steps", sflow_steps, 1, 200)
    if prompt is not None:
        check_request(prompt, 2)
    if person_prompt is not None:
        check_request("scene", 2, person_prompts=[person_prompt])
    check_out_dir(out)
    motion = open_motion(scene_file)  # read and checked; resampled and fitted below
    if motion.num_people < 2:
        raise UMFError(f"{scene_file}: one person, nobody to react to: generate it again with "
                       "another seed")  # fmt: skip
    if not 1 <= person <= motion.num_people:
        raise UMFError(f"{scene_file}: has {motion.num_people} people, no person {person}")
    text = prompt if prompt is not None else motion.text
    if not text.strip():
        raise UMFError(f"{scene_file}: has no prompt; give one with --prompt")
    config = peek_config(model)
    if config is not None:
        check_person_prompts(config, [person_prompt])
    most = (config.vae.max_frames if config is not None else 300) + 1
    if motion.frames > most:
        raise UMFError(f"{scene_file}: {motion.frames / FPS:.1f} s; the model re-rolls scenes of "
                       f"at most {(most - 1) / FPS:.1f} s")  # fmt: skip
    stem = out / f"reroll-p{person}-{_slug(text)}"
    check_targets(scene_targets(stem, wanted, motion.num_people))
    scene = open_scene(scene_file, motion)  # a 30 fps umf file as it is: the others bit for bit
    pipe = load_pipeline(model)
    warn_unknown(pipe, [text] + ([person_prompt] if person_prompt else []))
    new = pipe.reroll(scene, person, seed=seed, prompt=prompt, guidance=guidance,
                      sflow_steps=sflow_steps, anchor=anchor,
                      person_prompt=person_prompt)  # fmt: skip
    clean_stale(out)
    for path in write_scene(new, stem, wanted):
        typer.echo(f"wrote {path}")
