"""The models (and real data) an evaluation compares: each a `Contender` that generates
scenes for prompts and lengths, and the text-motion evaluators that score them."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from umf.data.clip import FPS
from umf.errors import UMFError
from umf.eval.evaluator import KINDS, MotionTextEvaluator, load_evaluator
from umf.eval.plan import (
    REAL,
    EvalPlan,
    batch_seed,
    bucket_frames,
    clamp_frames,
    cut,
    length_batches,
    model_label,
)
from umf.pipeline import Scene, UMFPipeline
from umf.representation import CONTACT


def _features(scene: Scene) -> np.ndarray:
    """Features in person 1's canonical frame, as the real items are scored: the decoded
    person 1 starts 0.1-0.2 m off the origin, which an evaluator would otherwise see."""
    from umf.representation import canonicalize_features

    return canonicalize_features(torch.from_numpy(scene.features)).numpy()


def _joints(scene: Scene) -> np.ndarray:
    """What the physics and accumulation sections score: the decoded positions
    (``raw_joints``), not the exports' fitted bodies (scenes are generated ``fit=False``)."""
    return scene.raw_joints


def _joints_contacts(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The decoded positions and contact labels (N, T, 4): enough to redo the delivery."""
    return scene.raw_joints, np.ascontiguousarray(scene.features[..., CONTACT])


@dataclass
class Contender:
    """A model under evaluation: the main one or a ``--variant``."""

    name: str
    path: Path
    pipe: UMFPipeline
    role: str = "model"  # or "variant"
    batch: int = 64
    progress: bool = True
    length_step: int = 1
    settings: dict[str, Any] = field(default_factory=dict)  # sampling arguments (--variant)
    timing: dict[int, list[float]] = field(default_factory=dict)  # people -> [seconds, scenes]

    @property
    def max_frames(self) -> int:
        return int(self.pipe.config.vae.max_frames)

    @property
    def reaction_only(self) -> bool:
        """Accumulation compares S-Flow with the noise-free reaction-only ablation."""
        label = self.name.lower().replace("-", "").replace("_", "")
        return bool(self.pipe.config.sflow.reaction_only) or "reactiononly" in label

    def generate(
        self,
        captions: Sequence[str],
        frames: Sequence[int],
        people: int,
        seed: int,
        what: str = "",
        keep: Callable[[Scene], Any] = lambda s: s,
    ) -> list[Any]:
        """``keep(scene)`` per caption, each at its own length (clamped), batched by length.

        Scenes are generated at :func:`bucket_frames` lengths and cut back to their own.
        ``keep`` drops what a section does not need batch by batch (thousands of MModality
        scenes would otherwise hold their joints and features at once).
        """
        frames = clamp_frames(frames, self.max_frames)
        sizes = bucket_frames(frames, self.length_step, self.max_frames)
        out: list[Any] = [None] * len(captions)
        bar = tqdm(total=len(captions), desc=f"{self.name} {what}".strip(), unit="scene",
                   disable=not self.progress, leave=False)  # fmt: skip
        for i, idx in enumerate(length_batches(sizes, self.batch)):
            t0 = time.perf_counter()
            scenes = self.pipe([captions[j] for j in idx], num_people=people,
                               seconds=sizes[idx[0]] / self.pipe.config.fps,
                               seed=batch_seed(seed, i), separate=False, fit=False,
                               **self.settings)  # fmt: skip
            spent = self.timing.setdefault(people, [0.0, 0])
            spent[0] += time.perf_counter() - t0
            spent[1] += len(idx)
            for j, s in zip(idx, scenes, strict=True):
                out[j] = keep(cut(s, frames[j]))
            bar.update(len(idx))
        bar.close()
        return out

    def features_fn(self, people: int):
        """The protocol's ``generate(captions, frames, seed)``: raw features per scene."""

        def generate(captions: list[str], frames: list[int], seed: int) -> list[np.ndarray]:
            return self.generate(captions, frames, people, seed, "protocol", _features)

        return generate

    def joints_fn(self, frames: int):
        """The accumulation study's ``generate(prompts, people, seed)``: joints per scene."""

        def generate(prompts: list[str], people: int, seed: int) -> list[np.ndarray]:
            lengths = [frames] * len(prompts)
            return self.generate(prompts, lengths, people, seed, f"N={people}", _joints)

        return generate


def load_contenders(
    checkpoint: Path,
    variants: Sequence[tuple[str, Path, dict[str, Any]] | tuple[str, Path]],
    device: str,
    plan: EvalPlan,
    progress: bool = True,
) -> list[Contender]:
    """The model and its variants, loaded and checked (unique names, the corpus frame rate).

    Variants naming the same directory share one loaded pipeline (step allocations)."""
    named = [(model_label(checkpoint), Path(checkpoint), "model", {})]
    named += [(v[0], Path(v[1]), "variant", dict(v[2]) if len(v) > 2 else {}) for v in variants]
    names = [n for n, *_ in named]
    if REAL in names or len(set(names)) != len(names):
        raise UMFError(f"model and variant names must be unique and not {REAL!r}: {names}")
    out: list[Contender] = []
    loaded: dict[str, UMFPipeline] = {}
    for name, path, role, settings in named:
        key = os.path.realpath(path)
        if key not in loaded:
            loaded[key] = UMFPipeline.from_pretrained(path).to(device)
        pipe = loaded[key]
        if pipe.config.fps != FPS:
            raise UMFError(f"{path}: a {pipe.config.fps} fps model; evaluation is at {FPS} fps")
        out.append(Contender(name, path, pipe, role, plan.batch, progress, plan.length_step,
                             settings))  # fmt: skip
    return out


def person_one_key(c: Contender) -> str:
    """What decides a contender's first person: the VAE, text encoder and P-Flow weights,
    the P-Flow sampling settings of the variant and of the model's config. Equal keys give
    identical single-person scenes under one seed, so the single-person protocol is scored
    once per key."""
    import hashlib

    h = hashlib.sha256()
    for module in (c.pipe.vae, c.pipe.pflow, c.pipe.text_encoder):
        for k, v in sorted(module.state_dict().items()):
            h.update(k.encode())
            h.update(v.detach().cpu().contiguous().numpy().tobytes())
    sampling = {k: c.settings.get(k) for k in ("pflow_steps", "guidance")}
    h.update(repr(sorted(sampling.items())).encode())
    cfg = c.pipe.config.to_dict()  # the model's own P-Flow defaults (steps, guidance, solver)
    h.update(repr([cfg[k] for k in ("fps", "text", "vae", "pflow")]).encode())
    return h.hexdigest()


# --------------------------------------------------------------------- evaluators
def load_evaluators(
    path: Path | None, cache_dir: Path | None, device: str
) -> dict[str, MotionTextEvaluator]:
    """Evaluators by kind from a run (``RUN/evaluator/KIND``), the bundled layout
    (``DIR/KIND``) or one checkpoint directory. ``interaction`` is required; a kind whose
    directory holds no checkpoint yet (its training still running) is left out."""
    if path is None:
        return {}
    path = Path(path)
    if not path.is_dir():
        raise UMFError(f"evaluator not found: {path}")
    found = {}
    for kind in KINDS:
        for cand in (path / "evaluator" / kind, path / kind):
            if any((cand / f).exists() for f in ("format.json", "best", "last")):
                found[kind] = load_evaluator(cand, cache_dir=cache_dir).to(device)
                break
    if not found:
        ev = load_evaluator(path, cache_dir=cache_dir).to(device)
        found[ev.kind] = ev
    if "interaction" not in found:
        raise UMFError(f"{path}: no two-person (interaction) evaluator; see `umf train evaluator`")
    return found
