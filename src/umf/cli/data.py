"""`umf data ...`: prepare the corpus, inspect it, render any item to look at it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from umf.errors import UMFError

app = typer.Typer(help="Prepare, inspect and render motion data.", no_args_is_help=True)


@app.command()
def prepare(
    out: Path = typer.Option(..., "--out", help="Corpus directory to write (reused if present)."),
    bandai: Path | None = typer.Option(
        None, help="Bandai data: the dataset-N.tar.xz archives, their folder, or a checkout."
    ),
    humanml3d: Path | None = typer.Option(
        None, help="HumanML3D root (new_joint_vecs/, texts/...)."
    ),
    interhuman: Path | None = typer.Option(None, help="InterHuman root (motions_processed/...)."),
    mocap: list[Path] = typer.Option(
        [],
        "--mocap",
        help="A folder of BVH / DeepMimic files, with optional captions.csv, "
        "takes.csv and skeleton.json (repeatable; docs/data.md).",
    ),
    seed: int = typer.Option(1234, help="Seed of the split-independent scene composer."),
    train_scenes: int = typer.Option(3000, help="Two-person scenes composed from train clips."),
    val_scenes: int = typer.Option(200, help="Two-person scenes from val clips."),
    test_scenes: int = typer.Option(300, help="Two-person scenes from test clips."),
    test_groups: int = typer.Option(200, help="Held-out groups of 3-6 people from test clips."),
    progress: bool = typer.Option(True, help="Show progress bars."),
) -> None:
    """Convert real data to the unified representation and compose multi-person scenes."""
    from umf.data.corpus import PrepareConfig, mocap_sources, prepare_corpus

    sources = {
        k: v
        for k, v in {"bandai": bandai, "humanml3d": humanml3d, "interhuman": interhuman}.items()
        if v is not None
    }
    sources.update(mocap_sources(mocap))
    cfg = PrepareConfig(
        seed=seed, train_scenes=train_scenes, val_scenes=val_scenes,
        test_scenes=test_scenes, test_groups=test_groups,
    )  # fmt: skip
    manifest = prepare_corpus(out, sources, cfg, progress=progress, log=typer.echo)
    _print_stats(manifest)
    typer.echo(f"corpus written to {out} ({manifest['seconds']} s)")


def _print_stats(manifest: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="umf corpus")
    for col in ("split", "clips", "frames", "hours", "scenes", "scene hours", "people/scene"):
        table.add_column(col, justify="right")
    for split, s in manifest["splits"].items():
        sizes = ", ".join(f"{k}:{v}" for k, v in sorted(s["scenes_by_size"].items()))
        table.add_row(split, str(s["clips"]), str(s["frames"]), f"{s['hours']:.2f}",
                      str(s["scenes"]), f"{s['scene_hours']:.2f}", sizes or "-")  # fmt: skip
    Console().print(table)
    if manifest.get("skipped"):
        typer.echo(f"{len(manifest['skipped'])} input file(s) skipped, listed in manifest.json")


@app.command()
def info(corpus: Path = typer.Argument(..., help="A prepared corpus directory.")) -> None:
    """Print a corpus's size per split and its relations."""
    from umf.data.corpus import Corpus

    c = Corpus.load(corpus)
    _print_stats(c.manifest)
    rel: dict[str, int] = {}
    for s in c.manifest["splits"].values():
        for k, v in s["scenes_by_relation"].items():
            rel[k] = rel.get(k, 0) + v
    typer.echo("relations: " + ", ".join(f"{k} {v}" for k, v in sorted(rel.items())))


def load_item(item: str, corpus: Path | None) -> tuple[np.ndarray, str]:
    """Joints (P, T, 22, 3) and a caption from a corpus id, an .npz scene or a .bvh file."""
    path = Path(item)
    if path.suffix.lower() in (".npz", ".bvh"):
        from umf.data.motion_file import load_motion

        motion = load_motion(path)
        return motion.joints, motion.text or path.stem
    if corpus is None:
        raise UMFError(f"{item!r} is not a file; give --corpus to look it up in a corpus")
    from umf.data.corpus import Corpus

    return Corpus.load(corpus).find(item)


@app.command()
def show(
    item: str = typer.Argument(..., help="Clip/scene id (with --corpus), or a .npz/.bvh file."),
    out: Path = typer.Option(..., "--out", help="Output .gif, .mp4 or .png (still strip)."),
    corpus: Path | None = typer.Option(None, help="Corpus directory for ids."),
    caption: str | None = typer.Option(None, help="Override the caption."),
    fps: float = typer.Option(30.0, help="Frames per second of the data."),
    stride: int = typer.Option(1, help="Render every n-th frame."),
) -> None:
    """Render a corpus item or a scene file as a stick-figure animation."""
    from umf import render
    from umf.validation import check_int

    joints, text = load_item(item, corpus)
    stride = check_int("--stride", stride, 1, max(1, joints.shape[1] - 1))
    text = caption if caption is not None else text
    if out.suffix == ".png":
        t = joints.shape[1]
        render.save_still(joints, out, frame_indices=tuple(np.linspace(0, t - 1, 5).astype(int)),
                          caption=text)  # fmt: skip
    else:
        render.render_animation(joints, out, caption=text, fps=fps, stride=stride)
    typer.echo(f"wrote {out}")


@app.command()
def list_items(
    corpus: Path = typer.Argument(..., help="A prepared corpus directory."),
    split: str = typer.Option("test_groups", help="train, val, test or test_groups."),
    limit: int = typer.Option(20, help="How many to list."),
) -> None:
    """List scene ids and captions of a split (to pick one for `umf data show`)."""
    from umf.data.corpus import Corpus

    c = Corpus.load(corpus)
    if split not in c.scenes:
        raise UMFError(f"no split {split!r}; choose from {', '.join(c.scenes)}")
    for r in c.scenes[split][:limit]:
        typer.echo(f"{r['id']}\t{r['num_people']}p {r['num_frames']}f\t{r['captions'][0]}")
