"""What `umf eval` does and how much of it: the plan of each section (protocol defaults,
`--quick`), the variants compared, and the scene lengths and seeds generation uses."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from umf.errors import UMFError
from umf.pipeline import Scene

Log = Callable[[str], None]


MIN_FRAMES = 15  # the pipeline's shortest scene


SCENE_FRAMES = 120  # 4 s: accumulation and speed scenes (or the model's maximum)


REAL = "real"


# --------------------------------------------------------------------- settings
@dataclass(frozen=True)
class EvalPlan:
    """How much work each section does (protocol defaults; :func:`make_plan` for --quick)."""

    quick: bool = False
    replications: int = 20
    mm_prompts: int = 100  # MModality costs mm_prompts x mm_samples scenes per replication
    mm_samples: int = 30
    mm_pairs: int = 10
    accumulation_sizes: tuple[int, ...] = (2, 3, 4, 5, 6, 7, 8)
    accumulation_prompts: int = 16
    pair_scenes: int | None = None  # relation / physics test pairs (None: all)
    group_scenes: int | None = None  # zero-shot groups (None: all)
    batch: int = 64  # prompts per pipeline call
    length_step: int = 1  # generate at lengths rounded up to multiples of this, then cut
    speed_repeats: int = 5
    seed: int = 0
    examples: int = 3
    motion_samples: int = 16  # generated people per label for the motion statistics (0: skip)
    split: str = "test"  # "val" to choose settings (sampling, checkpoints) without the test set


# Scored splits: "test" reports; "val" chooses (its pairs, no groups: groups exist only as
# the zero-shot test set). A setting chosen on "test" would flatter the report.
SPLITS = ("test", "val")


QUICK = EvalPlan(
    quick=True, replications=2, mm_prompts=8, mm_samples=5, accumulation_sizes=(2, 3, 4),
    accumulation_prompts=4, pair_scenes=64, group_scenes=8, speed_repeats=2, length_step=15,
    motion_samples=8,
)  # fmt: skip


def make_plan(
    quick: bool = False,
    replications: int | None = None,
    mm_prompts: int | None = None,
    mm_samples: int | None = None,
    seed: int = 0,
    batch: int = 64,
    length_step: int | None = None,
    split: str = "test",
) -> EvalPlan:
    """The plan of a run: full protocol defaults or --quick, then explicit overrides."""
    if split not in SPLITS:
        raise UMFError(f"--split must be one of {', '.join(SPLITS)}, got {split!r}")
    plan = QUICK if quick else EvalPlan()
    over = {"replications": replications, "mm_prompts": mm_prompts, "mm_samples": mm_samples,
            "length_step": length_step, "split": split}  # fmt: skip
    plan = dataclasses.replace(plan, seed=seed, batch=batch,
                               **{k: v for k, v in over.items() if v is not None})  # fmt: skip
    if plan.replications < 1:
        raise UMFError(f"--replications must be at least 1, got {plan.replications}")
    if plan.mm_prompts < 0:
        raise UMFError(f"--mm-prompts must be 0 (skip MModality) or more, got {plan.mm_prompts}")
    if plan.mm_prompts > 0 and plan.mm_samples < 2:
        raise UMFError(f"--mm-samples must be at least 2, got {plan.mm_samples}")
    if not 1 <= plan.length_step <= 300:
        raise UMFError(f"--length-step must be between 1 and 300 frames, got {plan.length_step}")
    if not 1 <= plan.batch <= 1024:
        raise UMFError(f"--batch must be between 1 and 1024, got {plan.batch}")
    return dataclasses.replace(plan, mm_pairs=min(plan.mm_pairs, plan.mm_samples))


VARIANT_SETTINGS = {"pflow_steps", "sflow_steps", "guidance"}


def parse_variant(text: str) -> tuple[str, Path, dict[str, Any]]:
    """``NAME=MODEL_DIR[:key=value...]`` -> (name, path, sampling settings).

    The settings are the pipeline's sampling arguments, so one trained model can be scored
    at several step allocations: ``25-25=src/umf/assets/model:pflow_steps=25,25``
    (``pflow_steps`` coarse -> fine, ``sflow_steps``, ``guidance``). One-line error otherwise.
    """
    name, sep, rest = text.partition("=")
    path, *pairs = rest.split(":")
    if not sep or not name.strip() or not path.strip():
        raise UMFError(f"--variant takes NAME=MODEL_DIR[:key=value...], got {text!r}")
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, eq, value = (x.strip() for x in pair.partition("="))
        if not eq or key not in VARIANT_SETTINGS:
            raise UMFError(f"--variant {name.strip()}: unknown setting {pair!r} (known: "
                           f"{', '.join(sorted(VARIANT_SETTINGS))})")  # fmt: skip
        try:
            if key == "pflow_steps":
                settings[key] = tuple(int(v) for v in value.split(","))
            elif key == "sflow_steps":
                settings[key] = int(value)
            else:
                settings[key] = float(value)
        except ValueError:
            raise UMFError(f"--variant {name.strip()}: bad value in {pair!r}") from None
    return name.strip(), Path(path.strip()), settings


def model_label(path: Path) -> str:
    """A model's name for tables: the name it was released under (``format.json``), else
    its directory, or the run's for ``RUN/model``."""
    import json

    path = Path(os.path.abspath(path))
    try:
        name = json.loads((path / "format.json").read_text()).get("name")
    except (OSError, ValueError, AttributeError):
        name = None
    if name:
        return str(name)
    return path.parent.name if path.name == "model" and path.parent.name else path.name


def default_evaluator_dir() -> Path:
    """Where a bundled evaluator (``interaction/``, ``single/``) lives in the package."""
    return Path(__file__).resolve().parents[1] / "assets" / "evaluator"


# --------------------------------------------------------------------- generation
def clamp_frames(frames: Sequence[int], max_frames: int) -> list[int]:
    """Frame counts the pipeline accepts: within [MIN_FRAMES, max_frames]."""
    return [min(max(int(f), MIN_FRAMES), max_frames) for f in frames]


def bucket_frames(frames: Sequence[int], step: int, max_frames: int) -> list[int]:
    """Generation lengths: each rounded up to a multiple of ``step`` (at most ``max_frames``).

    The pipeline makes one length per call, so exact test lengths (116 distinct among the
    300 Bandai test pairs) mean many small calls; a coarser step trades a little extra
    generated tail, cut off again, for far fewer calls. ``step`` 1 keeps exact lengths.
    """
    return [min(-(-int(f) // step) * step, max_frames) for f in frames]


def cut(scene: Scene, frames: int) -> Scene:
    """The scene's first ``frames`` frames (a copy, so the batch's arrays can be freed)."""
    if frames >= scene.num_frames:
        return scene
    return scene.frames(frames)


def length_batches(frames: Sequence[int], batch: int) -> list[list[int]]:
    """Item indices grouped by equal length, in chunks of at most ``batch``.

    The pipeline makes one length per call; grouping keeps every item at its own length.
    """
    groups: dict[int, list[int]] = {}
    for i, f in enumerate(frames):
        groups.setdefault(int(f), []).append(i)
    return [
        idx[i : i + batch] for _, idx in sorted(groups.items()) for i in range(0, len(idx), batch)
    ]


def batch_seed(seed: int, index: int) -> int:
    """An independent seed per pipeline call, reproducible from the caller's seed."""
    return int(np.random.SeedSequence([int(seed) % 2**63, index]).generate_state(1)[0])


def delivered_name(model: str) -> str:
    """The column of a model's delivered scenes."""
    return f"{model}, delivered"
