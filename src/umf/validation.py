"""One validation layer for generation requests and model configs, run before any model loads.

The CLI and the Python API call the same checks, so a bad value is one clear
:class:`UMFError` whichever way it came in, and never a traceback after minutes of
sampling. The bounds are documented in the README ("Generate"); change both together.
"""

from __future__ import annotations

import math
import numbers
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from umf.errors import UMFError

MAX_PEOPLE = 16
MIN_SECONDS, MAX_SECONDS = 0.5, 10.0
MAX_SEED = 2**64 - 1
MAX_GUIDANCE = 20.0
MAX_FLOW_STEPS = 200  # P-Flow steps of all stages together; S-Flow steps per added person
MAX_BATCH = 256
MAX_SCENES = 256  # scenes per call: prompts x batch
MAX_PROMPT_CHARS = 1000
# Memory cap: scenes are sampled in chunks of at most this many person-frames (16 scenes of
# 16 people x 10 s); the result does not depend on the chunking (per-scene random streams).
CHUNK_PERSON_FRAMES = 16 * 16 * 300
MIN_BODY_EXTENT = 0.2  # metres: a motion smaller than this in every axis is not a body


@dataclass(frozen=True)
class Request:
    """A checked generation request; ``sample_indices[i]`` numbers prompt i's samples."""

    prompts: tuple[str, ...]
    num_people: int
    seconds: float
    seed: int | None
    guidance: float | None
    pflow_steps: tuple[int, ...] | None
    sflow_steps: int | None
    sample_indices: tuple[int, ...]
    person_prompts: tuple[str | None, ...] = ()  # the K-th for person K (None: scene only)


# --------------------------------------------------------------------- scalars
def check_int(name: str, value: Any, lo: int, hi: int) -> int:
    """An integer (not a bool, not 2.5) within [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise UMFError(f"{name} must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise UMFError(f"{name} must be between {lo} and {hi}, got {value}")
    return int(value)


def check_float(name: str, value: Any, lo: float, hi: float) -> float:
    """A finite real number within [lo, hi] (NaN and infinities are refused by name)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise UMFError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise UMFError(f"{name} must be a finite number, got {value}")
    if not lo <= v <= hi:
        raise UMFError(f"{name} must be between {lo:g} and {hi:g}, got {value}")
    return v


def check_prompts(prompts: Any) -> tuple[str, ...]:
    """One string or a non-empty sequence of non-empty strings, each of bounded length."""
    if isinstance(prompts, str):
        prompts = [prompts]
    if not isinstance(prompts, Sequence) or isinstance(prompts, bytes):
        raise UMFError(f"the prompt must be a string or a list of strings, got {prompts!r:.60}")
    if not prompts:
        raise UMFError("the prompt is empty")
    if len(prompts) > MAX_SCENES:
        raise UMFError(f"at most {MAX_SCENES} prompts per call, got {len(prompts)}")
    return tuple(check_text(p) for p in prompts)


def check_text(p: Any, what: str = "prompt") -> str:
    """A non-empty string of at most MAX_PROMPT_CHARS characters a tokenizer can take."""
    if not isinstance(p, str):
        raise UMFError(f"every {what} must be a string, got {p!r:.60}")
    if not p.strip():
        raise UMFError(f"the {what} is empty")
    if len(p) > MAX_PROMPT_CHARS:
        raise UMFError(f"a {what} may have at most {MAX_PROMPT_CHARS} characters, got {len(p)}")
    try:
        p.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate ("\ud800"): no tokenizer takes it
        raise UMFError(f"the {what} is not valid text (unpaired surrogate in {p!r:.60})") from None
    return p


def check_person_prompts(person_prompts: Any, num_people: int) -> tuple[str | None, ...]:
    """Per-person prompts: a list, the K-th for person K, None (or absent) for a person who
    follows the scene prompt alone; never more prompts than people."""
    if person_prompts is None:
        return ()
    if isinstance(person_prompts, str | bytes) or not isinstance(person_prompts, Sequence):
        raise UMFError("person prompts must be a list (the K-th for person K), got "
                       f"{person_prompts!r:.60}")  # fmt: skip
    if len(person_prompts) > num_people:
        raise UMFError(f"{len(person_prompts)} person prompts for {num_people} "
                       f"{'person' if num_people == 1 else 'people'}")  # fmt: skip
    return tuple(None if p is None else check_text(p, "person prompt") for p in person_prompts)


def check_steps(steps: Any) -> tuple[int, ...] | None:
    """P-Flow steps per stage (coarse to fine): positive, at most MAX_FLOW_STEPS in all."""
    if steps is None:
        return None
    if isinstance(steps, numbers.Integral) and not isinstance(steps, bool):
        steps = (steps,)
    if not isinstance(steps, Sequence) or isinstance(steps, str) or not 1 <= len(steps) <= 8:
        raise UMFError(f"--steps takes 1 to 8 integers like 45,5, got {steps!r}")
    values = tuple(check_int("--steps", s, 1, MAX_FLOW_STEPS) for s in steps)
    if sum(values) > MAX_FLOW_STEPS:
        raise UMFError(f"--steps may total at most {MAX_FLOW_STEPS}, got {sum(values)}")
    return values


def default_sample_indices(prompts: Sequence[str]) -> tuple[int, ...]:
    """Each prompt's index among the earlier copies of the same prompt: 0 for the first."""
    seen: Counter[str] = Counter()
    out = []
    for p in prompts:
        out.append(seen[p])
        seen[p] += 1
    return tuple(out)


def check_request(
    prompts: Any,
    num_people: Any = 2,
    seconds: Any = 4.0,
    seed: Any = 0,
    guidance: Any = None,
    pflow_steps: Any = None,
    sflow_steps: Any = None,
    sample_indices: Any = None,
    person_prompts: Any = None,
) -> Request:
    """Every model-independent bound of a generation request, checked in one place."""
    texts = check_prompts(prompts)
    people = check_int("--people", num_people, 1, MAX_PEOPLE)
    secs = check_float("--seconds", seconds, MIN_SECONDS, MAX_SECONDS)
    seed = None if seed is None else check_int("--seed", seed, 0, MAX_SEED)
    if guidance is not None:
        guidance = check_float("--guidance", guidance, 0.0, MAX_GUIDANCE)
    if sflow_steps is not None:
        sflow_steps = check_int("--sflow-steps", sflow_steps, 1, MAX_FLOW_STEPS)
    if sample_indices is None:
        indices = default_sample_indices(texts)
    else:
        if isinstance(sample_indices, str | bytes) or not isinstance(sample_indices, Sequence):
            raise UMFError("sample_indices must be a list of integers, one per prompt")
        if len(sample_indices) != len(texts):
            raise UMFError(f"{len(sample_indices)} sample indices for {len(texts)} prompts")
        indices = tuple(check_int("a sample index", i, 0, 2**31 - 1) for i in sample_indices)
    steps = check_steps(pflow_steps)
    own = check_person_prompts(person_prompts, people)
    return Request(texts, people, secs, seed, guidance, steps, sflow_steps, indices, own)


def check_for_model(req: Request, config: Any, acting: bool = False) -> int:
    """The bounds that depend on the model (length, stage count); returns the frame count."""
    stages = config.pflow.num_stages
    if req.pflow_steps is not None and len(req.pflow_steps) not in (1, stages):
        raise UMFError(
            f"--steps needs {stages} count(s) for this model's {stages}-stage pyramid "
            f"(coarse to fine), got {len(req.pflow_steps)}"
        )
    if req.pflow_steps is not None and len(req.pflow_steps) == 1 and req.pflow_steps[0] < stages:
        raise UMFError(f"--steps {req.pflow_steps[0]} in total is fewer than this model's "
                       f"{stages} pyramid stages (at least one step each)")  # fmt: skip
    if acting:
        return 0
    frames = round(req.seconds * config.fps)
    if not 15 <= frames <= config.vae.max_frames:
        lo, hi = 15 / config.fps, config.vae.max_frames / config.fps
        raise UMFError(f"--seconds must be between {lo:.1f} and {hi:.1f}, got {req.seconds}")
    return frames


def check_batch(batch: Any, prompts: int) -> int:
    """Scenes per prompt; prompts x batch is capped at MAX_SCENES."""
    batch = check_int("--batch", batch, 1, MAX_BATCH)
    if batch * prompts > MAX_SCENES:
        raise UMFError(
            f"at most {MAX_SCENES} scenes per command: {prompts} prompt(s) x --batch {batch} "
            f"is {batch * prompts}"
        )
    return batch


def check_out_dir(out: Path) -> Path:
    """An output directory that exists or can be created; nothing is created here."""
    if out.is_symlink() and not out.exists():
        raise UMFError(f"--out {out} is a symbolic link to nothing ({os.readlink(out)})")
    if out.exists() and not out.is_dir():
        raise UMFError(f"--out {out} exists and is not a directory")
    parent = out
    while not parent.exists():
        if parent.parent == parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        raise UMFError(f"--out {out}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UMFError(f"--out {out}: {parent} is not writable")
    return out


def check_port(port: int) -> int:
    """A TCP port to listen on: 0 (any free one) to 65535."""
    if not 0 <= port <= 65535:
        raise UMFError(f"--port must be 0-65535 (0: any free port), got {port}")
    return port


def check_targets(paths: Sequence[Path]) -> None:
    """No output name may be taken by a directory (it could not be replaced)."""
    for p in paths:
        if p.is_dir():
            raise UMFError(f"cannot write {p}: a directory has that name")


def check_actor(actor: Any, fps: float, max_frames: int) -> np.ndarray:
    """Person 1's joints (T, 22, 3): finite, long enough, short enough, and body-sized."""
    if not isinstance(actor, np.ndarray):
        raise UMFError(f"the actor motion must be a numpy array, got {type(actor).__name__}")
    if actor.ndim != 3 or actor.shape[1:] != (22, 3):
        raise UMFError(f"the actor motion must be (T, 22, 3) joints, got {actor.shape}")
    most = max_frames + 1
    if not 16 <= actor.shape[0] <= most:
        raise UMFError(
            f"the actor motion must have 16..{most} frames ({16 / fps:.1f}-{most / fps:.1f} s), "
            f"got {actor.shape[0]}"
        )
    if not np.issubdtype(actor.dtype, np.number) or not np.isfinite(actor).all():
        raise UMFError("the actor motion contains NaN or infinite values")
    extent = float(np.ptp(actor, axis=1).max())
    if extent < MIN_BODY_EXTENT:
        raise UMFError(
            f"the actor motion spans only {extent:.3f} m: not a body (all joints at one point?)"
        )
    from umf.units import check_body_size, choose_unit

    unit, name = choose_unit(actor)
    check_body_size(actor, name, "the actor motion")
    if name not in ("m", "stature"):  # a body of an adult's size in another unit
        raise UMFError(f"the actor motion looks like it is in {name}, not metres (a body "
                       f"{1 / unit:g} times too large): multiply it by {unit:g}")  # fmt: skip
    return actor


def check_finite(x: Any, what: str) -> None:
    """Refuse non-finite output before anything is written, naming where it came from."""
    import torch

    ok = torch.isfinite(x).all() if isinstance(x, torch.Tensor) else np.isfinite(x).all()
    if not bool(ok):
        raise UMFError(f"non-finite values (NaN or inf) in {what}")


def check_device(device: str) -> str:
    """``cpu``, ``cuda`` or ``cuda:N`` that this machine has (``auto``: cuda when present)."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise UMFError(f"--device must be auto, cpu or cuda[:i], got {device!r}") from exc
    if dev.type not in ("cpu", "cuda"):
        raise UMFError(f"--device must be auto, cpu or cuda[:i], got {device!r}")
    if dev.type == "cuda":
        count = torch.cuda.device_count()
        if count == 0:
            raise UMFError(f"--device {device}: no CUDA device on this machine")
        if dev.index is not None and dev.index >= count:
            raise UMFError(f"--device {device}: this machine has {count} CUDA device(s)")
    return device


def chunk_size(num_people: int, frames: int, budget: int = CHUNK_PERSON_FRAMES) -> int:
    """Scenes sampled together so that one chunk holds at most ``budget`` person-frames."""
    return max(1, budget // max(1, num_people * frames))


def chunks(n: int, size: int) -> list[range]:
    """``range(n)`` cut into consecutive pieces of at most ``size``."""
    return [range(i, min(n, i + size)) for i in range(0, n, size)]
