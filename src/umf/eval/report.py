"""`umf eval`: one report of a trained model (and its variants) against real data.

Sections: (1) the text-motion protocol of SPEC 8 (FID, R-precision, MM-Dist, Diversity,
MModality; mean and 95% CI over replications) for two-person test scenes and, when a
single-person evaluator exists, single clips; (2) relation accuracy of generated test
pairs and zero-shot groups of 3-6; (3) physical plausibility; (4) error accumulation over
the person index; (5) speed (time, NFE, FLOPs); (6) example frames. Real data goes
through the same code and is the upper reference everywhere.

Everything is computed before anything is written; then the PNGs, ``metrics.json`` and
last ``report.md`` are written, each atomically, so a failure never leaves a report that
looks complete.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from umf.data.clip import FPS
from umf.data.corpus import Corpus
from umf.errors import UMFError
from umf.eval import accumulation as A
from umf.eval.evaluator import KINDS, MotionTextEvaluator, load_evaluator
from umf.eval.metrics import mean_ci
from umf.eval.physics import physics_report
from umf.eval.protocol import ProtocolConfig, corpus_items, score_protocol
from umf.eval.relations import real_scene_joints, relation_accuracy
from umf.io import atomic_path, write_json_atomic, write_text_atomic
from umf.pipeline import Scene, UMFPipeline, delivered_joints
from umf.representation import CONTACT
from umf.version import __version__

Log = Callable[[str], None]
MIN_FRAMES = 15  # the pipeline's shortest scene
SCENE_FRAMES = 120  # 4 s: accumulation and speed scenes (or the model's maximum)
REAL = "real"
PHYSICS_KEYS: dict[str, str] = {
    "penetration_cm": "inter-person penetration (cm) ↓",
    "penetration_frac": "frames penetrating > 1 cm ↓",
    "skate_ratio": "foot skating ratio ↓",
    "grounded_speed": "grounded foot speed (m/s) ↓",
    "float_ratio": "floating ratio ↓",
    "ground_pen_cm": "ground penetration (cm) ↓",
    "accel": "acceleration (m/s²)",
    "jerk": "jerk (m/s³) ↓",
}
PROTOCOL_KEYS: dict[str, str] = {
    "fid": "FID ↓",
    "r_precision_top1": "R-precision top-1 ↑",
    "r_precision_top2": "R-precision top-2 ↑",
    "r_precision_top3": "R-precision top-3 ↑",
    "mm_dist": "MM-Dist ↓",
    "diversity": "Diversity →",
    "multimodality": "MModality ↑",
    "r_precision_ceiling_top1": "R-precision ceiling top-1",
    "r_precision_ceiling_top3": "R-precision ceiling top-3",
}


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


# --------------------------------------------------------------------- sections
def protocol_section(
    evaluator: MotionTextEvaluator,
    corpus: Corpus,
    kind: str,
    contenders: Sequence[Contender],
    plan: EvalPlan,
    notes: list[str],
    log: Log,
) -> dict[str, Any] | None:
    """The protocol table of one evaluator kind: real vs every contender."""
    items = corpus_items(corpus, plan.split, kind)
    people = KINDS[kind]
    label = "two-person" if kind == "interaction" else "single-person"
    if len(items) < 3:
        notes.append(f"{label} protocol skipped: {plan.split} items {len(items)}, at least 3 "
                     "needed.")  # fmt: skip
        return None
    group = min(96, len(items))
    if group < 96:
        notes.append(f"{label} protocol: {len(items)} {plan.split} items, so R-precision groups of "
                     f"{group} instead of 96 (not comparable with published numbers).")  # fmt: skip
    longest = min(c.max_frames for c in contenders)
    clipped = sum(it.num_frames > longest for it in items)
    if clipped:
        notes.append(f"{label} protocol: {clipped} of {len(items)} {plan.split} items are longer "
                     f"than the models' {longest} frames; generated at {longest}.")  # fmt: skip
    cfg = ProtocolConfig(
        replications=plan.replications, group=group, mm_prompts=plan.mm_prompts,
        mm_samples=plan.mm_samples, mm_pairs=plan.mm_pairs, seed=plan.seed,
        max_frames=evaluator.cfg.max_frames,
    )  # fmt: skip
    evaluated = (len(items) // group) * group
    mm = min(plan.mm_prompts, evaluated) * plan.mm_samples  # the protocol's MModality draw
    results: dict[str, Any] = {}
    done: dict[str, str] = {}  # single person: person_one_key -> contender scored
    for c in contenders:
        key = person_one_key(c) if people == 1 else c.name
        if key in done:
            results[c.name] = results[done[key]]
            notes.append(f"{label} protocol: {c.name} has the first person of {done[key]} "
                         "(same VAE, P-Flow and sampling), so it shares its scores.")  # fmt: skip
            continue
        done[key] = c.name
        total = plan.replications * (evaluated + mm)
        log(f"{label} protocol, {c.name}: {plan.replications} replications x ({evaluated} "
            f"scenes + {mm} for MModality) = {total} scenes")  # fmt: skip
        res = score_protocol(evaluator, items, c.features_fn(people), cfg, log)
        results.setdefault(REAL, res["real"])
        results[c.name] = res["generated"]
    return {"items": len(items), "group": group, "people": people, "split": plan.split,
            "results": results}  # fmt: skip


def scene_records(corpus: Corpus, split: str, limit: int | None) -> list[dict[str, Any]]:
    """The first ``limit`` scene recipes of a split (all when None)."""
    recipes = list(corpus.scenes.get(split, []))
    return recipes if limit is None else recipes[:limit]


def generate_records(
    c: Contender,
    records: Sequence[dict[str, Any]],
    seed: int,
    keep: Callable[[Scene], Any] = _joints,
) -> list[Any]:
    """``keep(scene)`` (default: joints) for scene records: their captions, sizes, lengths."""
    out: list[np.ndarray | None] = [None] * len(records)
    for people in sorted({r["num_people"] for r in records}):
        idx = [i for i, r in enumerate(records) if r["num_people"] == people]
        caps = [records[i]["captions"][0] for i in idx]
        frames = [records[i]["num_frames"] for i in idx]
        joints = c.generate(caps, frames, people, seed + people, f"scenes of {people}", keep)
        for i, j in zip(idx, joints, strict=True):
            out[i] = j
    return out


def proportion_ci(p: float, n: int) -> float:
    """95% half-width of a proportion over n scenes (normal approximation: 0 at p = 0, 1)."""
    return 1.96 * math.sqrt(p * (1 - p) / n) if n and math.isfinite(p) else float("nan")


def accuracy_summary(records: Sequence[dict[str, Any]], joints: Sequence[np.ndarray]) -> dict:
    """:func:`relation_accuracy` plus the 95% CI of its scene accuracy."""
    acc = relation_accuracy(records, joints, FPS)
    acc["scene_accuracy_ci"] = proportion_ci(acc["scene_accuracy"], acc["num_scenes"])
    return acc


def physics_summary(joints: Sequence[np.ndarray]) -> dict[str, Any]:
    """Mean and 95% CI over scenes of every physics key (scene = mean over its people)."""
    reports = [physics_report(j, FPS) for j in joints]
    out: dict[str, Any] = {}
    for key in PHYSICS_KEYS:
        vals = [r[key] for r in reports if math.isfinite(r.get(key, float("nan")))]
        out[key] = mean_ci(vals) if vals else (float("nan"), float("nan"))
    out["penetration_max_cm"] = max(r["penetration_max_cm"] for r in reports)
    return out


@dataclass
class SceneSet:
    """Test records with their real joints and every contender's generated joints: the raw
    model output, and after them, under ``"<model>, delivered"``, the main model's same
    scenes as the default pipeline hands them out (:func:`umf.pipeline.delivered_joints`).
    """

    name: str
    records: list[dict[str, Any]]
    real: list[np.ndarray]
    generated: dict[str, list[np.ndarray]] = field(default_factory=dict)


def delivered_name(model: str) -> str:
    """The column of a model's delivered scenes."""
    return f"{model}, delivered"


def scene_sets(
    corpus: Corpus, contenders: Sequence[Contender], plan: EvalPlan, notes: list[str], log: Log
) -> list[SceneSet]:
    """Test pairs and zero-shot groups, real and generated (shared by sections 2, 3, 6)."""
    sets = []
    for name, split, limit in (("pairs", plan.split, plan.pair_scenes),
                               ("groups", f"{plan.split}_groups", plan.group_scenes)):  # fmt: skip
        records = scene_records(corpus, split, limit)
        total = len(corpus.scenes.get(split, []))
        if not records:
            notes.append(f"no {split} scenes in the corpus: relation/physics {name} skipped.")
            continue
        if len(records) < total:
            notes.append(f"{name}: the first {len(records)} of {total} {split} scenes.")
        longest = min(c.max_frames for c in contenders)
        clipped = sum(r["num_frames"] > longest for r in records)
        if clipped:
            notes.append(f"{name}: {clipped} scenes are longer than the models' {longest} "
                         "frames; they are generated at that length.")  # fmt: skip
        s = SceneSet(name, records, real_scene_joints(corpus, records))
        delivered = {}
        for c in contenders:
            log(f"relations/physics, {c.name}: generating {len(records)} {name}")
            if c.role != "model":
                s.generated[c.name] = generate_records(c, records, plan.seed + 200_000)
                continue
            both = generate_records(c, records, plan.seed + 200_000, _joints_contacts)
            s.generated[c.name] = [j for j, _ in both]
            delivered[delivered_name(c.name)] = [delivered_joints(j, k) for j, k in both]
        s.generated |= delivered  # the delivered columns after every raw one
        sets.append(s)
    return sets


def relations_section(sets: Sequence[SceneSet]) -> dict[str, dict[str, Any]]:
    """Relation accuracy per scene set and source, plus all sets pooled."""
    out: dict[str, dict[str, Any]] = {}
    for s in sets:
        out[s.name] = {REAL: accuracy_summary(s.records, s.real)}
        out[s.name] |= {n: accuracy_summary(s.records, j) for n, j in s.generated.items()}
    if len(sets) > 1:
        recs = [r for s in sets for r in s.records]
        out["all"] = {REAL: accuracy_summary(recs, [j for s in sets for j in s.real])}
        for n in sets[0].generated:
            out["all"][n] = accuracy_summary(recs, [j for s in sets for j in s.generated[n]])
    return out


def physics_section(sets: Sequence[SceneSet]) -> dict[str, dict[str, Any]]:
    """Physics per scene set and source."""
    out: dict[str, dict[str, Any]] = {}
    for s in sets:
        out[s.name] = {REAL: physics_summary(s.real)}
        out[s.name] |= {n: physics_summary(j) for n, j in s.generated.items()}
    return out


def accumulation_prompts(corpus: Corpus, count: int, split: str = "test") -> list[str]:
    """Group captions (pair captions when there are no groups), first caption each, unique."""
    recipes = corpus.scenes.get(f"{split}_groups") or corpus.scenes.get(split, [])
    prompts = list(dict.fromkeys(r["captions"][0] for r in recipes))
    return prompts[:count]


def accumulation_section(
    corpus: Corpus, contenders: Sequence[Contender], plan: EvalPlan, log: Log
) -> list[dict[str, Any]]:
    """The per-person-index study for the model and every reaction-only variant."""
    prompts = accumulation_prompts(corpus, plan.accumulation_prompts, plan.split)
    if not prompts:
        return []
    rows: list[dict[str, Any]] = []
    for c in contenders:
        if c.role == "model" or c.reaction_only:
            frames = min(SCENE_FRAMES, c.max_frames)
            log(f"accumulation, {c.name}: N = {', '.join(map(str, plan.accumulation_sizes))}")
            rows += A.accumulation_table(c.joints_fn(frames), prompts, plan.accumulation_sizes,
                                         plan.seed + 300_000, FPS, c.name)  # fmt: skip
    return rows


def flops_of(fn: Callable[[], Any]) -> int:
    """FLOPs torch counts (matrix products, attention) for one call of ``fn``."""
    from torch.utils.flop_counter import FlopCounterMode

    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        fn()
    return int(counter.get_total_flops())


def speed_section(c: Contender, prompt: str, repeats: int, seed: int) -> dict[str, Any]:
    """Latency of one N = 2 scene (batch 1, 4 s or the model's maximum), NFE and FLOPs."""
    frames = min(SCENE_FRAMES, c.max_frames)

    def one() -> Scene:
        return c.pipe(
            prompt, num_people=2, seconds=frames / c.pipe.config.fps, seed=seed, **c.settings
        )[0]

    one()  # warm-up: lazy initialisation and caches out of the timing
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        scene = one()
        times.append(time.perf_counter() - t0)
    mean, ci = mean_ci(times)
    text = flops_of(
        lambda: (c.pipe.text_encoder.encode([prompt]), c.pipe.text_encoder.encode([""]))
    )
    spent, count = c.timing.get(2, [float("nan"), 0])
    return {
        "frames": frames, "people": 2, "repeats": repeats, "nfe": int(scene.meta["nfe"]),
        "seconds_per_scene": mean, "seconds_ci": ci,
        "batched_seconds_per_scene": spent / count if count else float("nan"),
        "flops": flops_of(one), "text_encoder_flops": text,
    }  # fmt: skip


# --------------------------------------------------------------------- figures
def write_examples(sets: Sequence[SceneSet], model: str, path: Path, count: int) -> list[str]:
    """A PNG of a few generated scenes (pairs first, then one group), one strip each."""
    from PIL import Image

    from umf.render import save_still

    pairs = [(s, i) for s in sets if s.name == "pairs" for i in range(len(s.records))]
    groups = [(s, i) for s in sets if s.name == "groups" for i in range(len(s.records))]
    picks = pairs[: count - min(1, len(groups))] + groups[:1]
    captions, strips = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (s, i) in enumerate(picks):
            caption = s.records[i]["captions"][0]
            png = save_still(s.generated[model][i], Path(tmp) / f"{k}.png", caption=caption,
                             size=(320, 240))  # fmt: skip
            strips.append(np.asarray(Image.open(png).convert("RGB")))
            captions.append(f"{caption} ({s.records[i]['num_people']} people)")
    if not strips:
        return []
    width = max(a.shape[1] for a in strips)
    padded = [np.pad(a, ((0, 0), (0, width - a.shape[1]), (0, 0)), constant_values=255)
              for a in strips]  # fmt: skip
    with atomic_path(path) as tmp_png:
        Image.fromarray(np.concatenate(padded, axis=0)).save(tmp_png, format="PNG")
    return captions


def plot_relations(relations: dict[str, dict[str, Any]], path: Path) -> None:
    """Grouped bars: accuracy per check kind, one bar per source, a panel per scene set."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = [n for n in ("pairs", "groups") if n in relations]
    fig = Figure(figsize=(6.5 * len(names), 3.6), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    for ax, name in zip(fig.subplots(1, len(names), squeeze=False)[0], names, strict=True):
        sources = list(relations[name])
        kinds = sorted({k for acc in relations[name].values() for k in acc["by_kind"]})
        width = 0.8 / len(sources)
        for i, src in enumerate(sources):
            vals = [relations[name][src]["by_kind"].get(k, {}).get("accuracy", np.nan)
                    for k in kinds]  # fmt: skip
            ax.bar(np.arange(len(kinds)) + i * width, vals, width, label=src)
        ax.set_xticks(np.arange(len(kinds)) + 0.4 - width / 2, kinds, rotation=35, ha="right")
        ax.set_ylim(0, 1.25)
        ax.set_title(f"relation checks passed: {name}", fontsize=10)
        ax.legend(fontsize=8, ncol=len(sources), loc="upper center")
        ax.grid(axis="y", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


# --------------------------------------------------------------------- markdown
def fmt(value: Any, ci: Any = None, digits: int = 3) -> str:
    """``mean ± ci`` (or the value alone); missing or non-finite values are a dash."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:,}"
    value = 0.0 if round(value, digits) == 0 else value  # no "-0.000"
    if ci is None or not math.isfinite(ci):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {ci:.{digits}f}"


def md_table(header: Sequence[str], rows: Sequence[Sequence[str]], left: int = 1) -> str:
    """A GitHub markdown table, the first ``left`` columns left-aligned, the rest right."""
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join([":---"] * left + ["---:"] * (len(header) - left)) + "|"]  # fmt: skip
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _pair(v: Any) -> tuple[Any, Any]:
    return (v[0], v[1]) if isinstance(v, list | tuple) else (v, None)


def headline_rows(results: dict[str, Any], sources: Sequence[str]) -> list[list[str]]:
    """The key numbers, one row each, one column per source (real first)."""
    proto = ((results.get("protocol") or {}).get("interaction") or {}).get("results", {})
    rel, phys, speed = results.get("relations", {}), results.get("physics", {}), results["speed"]
    rows = []
    pairs = f"{results.get('meta', {}).get('split', 'test')} pairs"
    for key in ("fid", "r_precision_top3", "mm_dist", "diversity", "multimodality"):
        if proto:
            rows.append([PROTOCOL_KEYS[key]] + [fmt(*_pair(proto.get(s, {}).get(key)))
                                                for s in sources])  # fmt: skip
    for name, label in (("pairs", pairs), ("groups", "groups of 3-6, zero-shot")):
        if name in rel:
            rows.append([f"relation accuracy, {label} ↑"] + [
                fmt(rel[name][s]["scene_accuracy"], rel[name][s]["scene_accuracy_ci"])
                for s in sources
            ])  # fmt: skip
    for name in ("pairs", "groups"):
        for key in ("penetration_cm", "skate_ratio"):
            if name in phys:
                rows.append([f"{PHYSICS_KEYS[key]}, {name}"] + [fmt(*_pair(phys[name][s][key]))
                                                                 for s in sources])  # fmt: skip
    # the same scenes as a user's files hold them (separated, fitted, feet pinned)
    delivered = [delivered_name(s) for s in sources]
    for name, label in (("pairs", pairs), ("groups", "groups of 3-6")):
        if any(d in rel.get(name, {}) for d in delivered):
            rows.append([f"relation accuracy, {label}, delivered ↑"] + [
                fmt(rel[name][d]["scene_accuracy"], rel[name][d]["scene_accuracy_ci"])
                if d in rel[name] else "—" for d in delivered
            ])  # fmt: skip
        for key in ("penetration_cm", "skate_ratio"):
            if any(d in phys.get(name, {}) for d in delivered):
                rows.append([f"{PHYSICS_KEYS[key]}, {name}, delivered"] + [
                    fmt(*_pair(phys[name][d][key])) if d in phys[name] else "—"
                    for d in delivered
                ])  # fmt: skip
    rows.append(["seconds per scene, N=2, batch 1"] + [
        fmt(speed[s]["seconds_per_scene"], speed[s]["seconds_ci"]) if s in speed else "—"
        for s in sources
    ])  # fmt: skip
    rows.append(["NFE"] + [fmt(speed[s]["nfe"]) if s in speed else "—" for s in sources])
    return rows


def protocol_markdown(section: dict[str, Any], title: str) -> str:
    res = section["results"]
    sources = list(res)
    keys = [k for k in PROTOCOL_KEYS if any(k in v for v in res.values())]
    rows = [[PROTOCOL_KEYS[k]] + [fmt(*_pair(res[s].get(k))) for s in sources] for k in keys]
    head = (f"{title}: {section['items']} {section.get('split', 'test')} items, groups of "
            f"{section['group']}; "
            "mean ± 95% CI over replications.")  # fmt: skip
    return head + "\n\n" + md_table(["metric", *sources], rows)


def relations_markdown(relations: dict[str, dict[str, Any]]) -> str:
    parts = []
    for name, by_source in relations.items():
        sources = list(by_source)
        first = by_source[sources[0]]
        rows = [
            ["scenes passing every check ↑"]
            + [fmt(a["scene_accuracy"], a["scene_accuracy_ci"]) for a in by_source.values()],
            ["checks passed ↑"] + [fmt(a["check_accuracy"]) for a in by_source.values()],
            ["mean over check kinds ↑"] + [fmt(a["kind_accuracy"]) for a in by_source.values()],
        ]
        kinds = sorted({k for a in by_source.values() for k in a["by_kind"]})
        rows += [[f"kind: {k} ({first['by_kind'].get(k, {}).get('count', 0)} checks)"]
                 + [fmt(a["by_kind"].get(k, {}).get("accuracy")) for a in by_source.values()]
                 for k in kinds]  # fmt: skip
        rels = sorted({k for a in by_source.values() for k in a["by_relation"]})
        rows += [[f"relation: {r}"] + [fmt(a["by_relation"].get(r)) for a in by_source.values()]
                 for r in rels]  # fmt: skip
        title = f"**{name}** ({first['num_scenes']} scenes, {first['num_checks']} checks)"
        parts.append(title + "\n\n" + md_table(["", *sources], rows))
    return "\n\n".join(parts)


def physics_markdown(physics: dict[str, dict[str, Any]]) -> str:
    parts = []
    for name, by_source in physics.items():
        sources = list(by_source)
        rows = [[label] + [fmt(*_pair(by_source[s][k])) for s in sources]
                for k, label in PHYSICS_KEYS.items()]  # fmt: skip
        rows.append(["deepest overlap (cm)"]
                    + [fmt(by_source[s]["penetration_max_cm"]) for s in sources])  # fmt: skip
        parts.append(f"**{name}** (mean ± 95% CI over scenes)\n\n"
                     + md_table(["", *sources], rows))  # fmt: skip
    return "\n\n".join(parts)


def accumulation_markdown(table: Sequence[dict[str, Any]]) -> str:
    variants = list(dict.fromkeys(r["variant"] for r in table))
    ks = sorted({r["k"] for r in table})
    rows = []
    for v in variants:
        for metric in ("penetration_prev_cm", "facing_p1_deg", "distance_p1_m", "skate_ratio"):
            got = dict(zip(*A.index_curve(table, v, metric), strict=True))
            if got:
                rows.append([f"{v}: {A.METRICS[metric]}"] + [fmt(got.get(k)) for k in ks])
    return md_table(["pooled over N", *[f"k={k}" for k in ks]], rows)


def speed_markdown(speed: dict[str, dict[str, Any]]) -> str:
    rows = []
    for name, s in speed.items():
        rows.append(
            [
                name,
                fmt(s["nfe"]),
                fmt(s["seconds_per_scene"], s["seconds_ci"]),
                fmt(s["batched_seconds_per_scene"], digits=4),
                fmt(s["flops"] / 1e9, digits=2),
                fmt(s["text_encoder_flops"] / 1e9, digits=2),
            ]
        )
    some = next(iter(speed.values()))
    head = (f"One scene of {some['people']} people, {some['frames']} frames, batch 1 "
            f"(mean ± 95% CI over {some['repeats']} runs after a warm-up). Batched: the "
            "evaluation's own generation of N=2 scenes (up to the batch size per call, one "
            "length per call). FLOPs: torch.utils.flop_counter (matrix products and attention; "
            "element-wise operations are not counted), text encoder included; its share in "
            "the last column.")  # fmt: skip
    header = ["model", "NFE", "s / scene", "s / scene batched", "GFLOPs / scene", "of which text"]
    return head + "\n\n" + md_table(header, rows)


def motion_section(corpus: Corpus, contenders: Sequence[Contender], plan: EvalPlan,
                   log: Log) -> dict[str, Any]:  # fmt: skip
    """Per-label body statistics of generated single people vs the real clips of that label
    (:mod:`umf.eval.motion_stats`): what a person looking at the motion would check."""
    from umf.eval import motion_stats as MS

    real = MS.real_joints_by_label(corpus)
    out: dict[str, Any] = {}
    for c in contenders:
        made: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}

        def generate(prompt: str, n: int, c: Contender = c, made: dict = made) -> list:
            if (prompt, n) not in made:  # joints and contacts: raw and delivered share a draw
                prompts, frames = [prompt] * n, [120] * n
                made[prompt, n] = c.generate(prompts, frames, 1, plan.seed, "motion statistics",
                                             _joints_contacts)  # fmt: skip
            return made[prompt, n]

        ways = {c.name: lambda p, n: [j[0] for j, _ in generate(p, n)]}
        if c.role == "model":  # as delivered too: anchored feet, fitted body
            ways[delivered_name(c.name)] = lambda p, n: [delivered_joints(j, k)[0]
                                                         for j, k in generate(p, n)]  # fmt: skip
        for name, way in ways.items():
            rows = MS.check_labels(real, way, samples=plan.motion_samples)
            passes = MS.label_passes(rows)
            out[name] = {"checks": [dataclasses.asdict(r) for r in rows], "labels": passes,
                         "passed": sum(passes.values()), "total": len(passes)}  # fmt: skip
            log(f"{name}: motion statistics {sum(passes.values())}/{len(passes)} labels")
    return out


def reconstruction_section(
    corpus: Corpus, contenders: Sequence[Contender], split: str = "test"
) -> dict[str, Any]:
    """VAE reconstructions of the real single-person clips of a split, per feature group
    (:mod:`umf.eval.reconstruction`): what the flows can at best reach."""
    from umf.eval.protocol import corpus_items
    from umf.eval.reconstruction import reconstruct, reconstruction_metrics

    items = corpus_items(corpus, split, "single")
    most = contenders[0].max_frames
    real = [it.features[0][:most] for it in items]
    out: dict[str, Any] = {}
    for c in contenders:
        rec = reconstruct(c.pipe.vae, c.pipe.normalizer, real)
        out[c.name] = reconstruction_metrics(real, rec)
    return out


def motion_markdown(motion: dict[str, Any]) -> str:
    from umf.eval.motion_stats import FEW_REAL, LabelCheck, few_real_clips, format_checks

    parts = []
    for name, sec in motion.items():
        rows = [LabelCheck(**{**r, "real_q": tuple(r["real_q"])}) for r in sec["checks"]]
        few = few_real_clips(rows)
        note = ""
        if few:
            named = ", ".join(f"{k} ({v})" for k, v in few.items())
            ok = sum(v for k, v in sec["labels"].items() if k not in few)
            note = (f" Labels with fewer than {FEW_REAL} real clips in the corpus: {named}; "
                    "their range is those clips' own values (one clip: zero width). Without "
                    f"them: {ok} of {sec['total'] - len(few)}.")  # fmt: skip
        parts += [f"**{name}**: {sec['passed']} of {sec['total']} labels within the real "
                  "clips' interquartile range (widened by a quarter of it) on every "
                  f"statistic.{note}", "", format_checks(rows), ""]  # fmt: skip
    return "\n".join(parts)


def reconstruction_markdown(rec: dict[str, Any]) -> str:
    keys = [
        "mpjpe_m",
        "mpjpe_root_relative_m",
        "wrist_error_m",
        "r2_trajectory",
        "r2_heading",
        "r2_positions",
        "r2_velocities",
        "r2_rotations",
        "r2_contacts",
    ]
    rows = [[k] + [fmt(rec[n][k]) for n in rec] for k in keys]
    return md_table(["", *rec], rows)


def render_markdown(results: dict[str, Any]) -> str:
    """report.md from the collected results (the same numbers as metrics.json)."""
    meta, sources = results["meta"], [s["name"] for s in results["sources"]]
    mode = "quick (--quick: small replication counts; not for publication)" if meta["quick"] \
        else "full protocol"  # fmt: skip
    if meta.get("split", "test") != "test":
        mode += (f", on the **{meta['split']} split** (for choosing settings; report test "
                 "numbers)")  # fmt: skip
    out = [f"# UMF evaluation: {meta['model']}", "",
           f"Mode: {mode}. Real data is the upper reference; ↓ lower is better, ↑ higher, "
           "→ closer to real.", "",
           md_table(["", *sources], headline_rows(results, sources)), "",
           f"- command: `{meta['command']}`",
           f"- date: {meta['date']}; wall time {meta['wall_seconds']:.0f} s",
           f"- machine: {meta['machine']}; umf {meta['umf_version']}, torch {meta['torch']}",
           "- models: " + "; ".join(f"{s['name']} = `{s['path']}`" for s in results["sources"]
                                    if s.get("path")),
           f"- corpus: `{meta['corpus']}`; evaluator: `{meta['evaluator']}`"]  # fmt: skip
    if results["notes"]:
        out += ["", "Notes:", ""] + [f"- {n}" for n in results["notes"]]
    proto = results.get("protocol") or {}
    out += ["", "## 1. Text-motion protocol", ""]
    if not proto:
        out.append("No evaluator: pass `--evaluator RUN` (from `umf train evaluator`).")
    for kind, title in (("interaction", "Two people"), ("single", "Single person (P-Flow)")):
        if proto.get(kind):
            out += [protocol_markdown(proto[kind], title), ""]
    out += [
        "## 2. Relation accuracy",
        "",
        "Generated from each test scene's first caption with its number of people and "
        "length; checked against the scene's relation record (`umf.eval.relations`).",
        "",
    ]
    if results.get("relations"):
        out += [relations_markdown(results["relations"]), "", "![relations](relations.png)"]
    out += [
        "",
        "## 3. Physics",
        "",
        "Scored on the decoded joints (`Scene.raw_joints`): the raw model output, before "
        "the kinematic fit and foot clean-up that every exported file carries "
        "(`umf.kinematics`). Relations and error accumulation score them too. The column "
        '"<model>, delivered" scores the same scenes as the default pipeline hands them '
        "out (`umf.pipeline.delivered_joints`): planted feet anchored (`umf.anchoring`: "
        "a gliding body is moved back by its planted foot's slide), people 2..N shifted "
        "apart on the floor (`umf.separation`), then one rigid body each with planted feet "
        "pinned.",
        "",
    ]
    if results.get("physics"):
        out.append(physics_markdown(results["physics"]))
    out += ["", "## 4. Error accumulation over the person index", ""]
    if results.get("accumulation"):
        out += [f"Prompts: {len(results['accumulation_prompts'])} group captions, N = "
                f"{', '.join(map(str, results['plan']['accumulation_sizes']))}; "
                "table in `accumulation.csv`.", "",
                accumulation_markdown(results["accumulation"]), "",
                "![accumulation](accumulation.png)"]  # fmt: skip
    if results.get("motion"):
        out += ["", "## 5. Motion statistics per label (single person)", "",
                "Generated from each label's prompt (4 s) and compared with the real clips "
                "of that label (`umf.eval.motion_stats`); a mean pose fails them, and a "
                "raised hand that wobbles fails the wave (right_wrist_swings: turns per "
                "second after at least 10 cm of side-to-side travel). "
                "\"<model>, delivered\": the same people as the pipeline hands them out "
                "(feet anchored, body fitted; section 3).", "",
                motion_markdown(results["motion"])]  # fmt: skip
    if results.get("reconstruction"):
        split = meta.get("split", "test")
        out += ["", f"## 6. VAE reconstruction of the real single-person {split} clips", "",
                "Posterior means decoded; R² per feature group against the per-dimension "
                "mean (1 perfect, 0 the mean pose; `umf.eval.reconstruction`).", "",
                reconstruction_markdown(results["reconstruction"])]  # fmt: skip
    out += ["", "## 7. Speed", "", speed_markdown(results["speed"]), ""]
    if results.get("examples"):
        out += [
            "## 8. Examples",
            "",
            f"Generated by {meta['model']}: " + "; ".join(results["examples"]) + ".",
            "",
            "![examples](examples.png)",
            "",
        ]
    return "\n".join(out)


# --------------------------------------------------------------------- the whole run
@dataclass
class EvalRequest:
    """Everything `umf eval` was asked to do."""

    checkpoint: Path
    corpus: Path
    out: Path
    evaluator: Path | None = None
    variants: list[tuple[str, Path, dict[str, Any]]] = field(default_factory=list)
    plan: EvalPlan = field(default_factory=EvalPlan)
    device: str = "cpu"
    progress: bool = True
    command: str = ""


def machine_info(device: str) -> str:
    """CPU (and GPU) in one line, for the report header."""
    cpu = f"{platform.machine()}, {os.cpu_count()} CPUs, torch threads: {torch.get_num_threads()}"
    if device.startswith("cuda"):
        cpu += f", {torch.cuda.get_device_name(torch.device(device))}"
    return f"{platform.node()} ({platform.system()}, {cpu})"


def jsonable(x: Any) -> Any:
    """Plain JSON types; non-finite floats become null."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def run_eval(req: EvalRequest, log: Log = print) -> Path:
    """Evaluate, then write the report into ``req.out``; returns the report's path."""
    t0 = time.perf_counter()
    plan, notes = req.plan, []
    corpus = Corpus.load(req.corpus)
    contenders = load_contenders(req.checkpoint, req.variants, req.device, plan, req.progress)
    if plan.length_step > 1:
        notes.append(f"generation lengths rounded up to multiples of {plan.length_step} frames "
                     "(fewer, larger pipeline calls), then cut back to each test item's "
                     "length (--length-step 1: exact).")  # fmt: skip
    evaluators = load_evaluators(req.evaluator, corpus.root / "text-cache", req.device)
    if not evaluators:
        notes.append("no evaluator given and none bundled: the protocol tables are missing.")
    elif "single" not in evaluators:
        notes.append("no single-person evaluator: the single-person table is missing.")
    protocol = {kind: protocol_section(ev, corpus, kind, contenders, plan, notes, log)
                for kind, ev in evaluators.items()}  # fmt: skip
    sets = scene_sets(corpus, contenders, plan, notes, log)
    relations, physics = relations_section(sets), physics_section(sets)
    table = accumulation_section(corpus, contenders, plan, log)
    prompt = next((s.records[0]["captions"][0] for s in sets), "two people bow to each other")
    motion = motion_section(corpus, contenders, plan, log) if plan.motion_samples else {}
    reconstruction = reconstruction_section(corpus, contenders, plan.split)
    speed = {c.name: speed_section(c, prompt, plan.speed_repeats, plan.seed) for c in contenders}
    if plan.mm_prompts and evaluators:
        notes.append(f"MModality: {plan.mm_prompts} prompts x {plan.mm_samples} samples = "
                     f"{plan.mm_prompts * plan.mm_samples} extra scenes per replication and "
                     "model (--mm-prompts, --mm-samples).")  # fmt: skip

    req.out.mkdir(parents=True, exist_ok=True)
    if table:
        A.save_table(table, req.out / "accumulation.csv")
        A.plot_accumulation(table, req.out / "accumulation.png")
    if relations:
        plot_relations(relations, req.out / "relations.png")
    main = contenders[0]
    examples = write_examples(sets, main.name, req.out / "examples.png", plan.examples)
    results = {
        "meta": {
            "model": main.name, "command": req.command, "quick": plan.quick,
            "split": plan.split, "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": machine_info(req.device), "device": req.device,
            "umf_version": __version__, "torch": torch.__version__,
            "corpus": str(req.corpus), "evaluator": str(req.evaluator) if req.evaluator else None,
            "wall_seconds": time.perf_counter() - t0,
        },
        "plan": dataclasses.asdict(plan),
        "sources": [{"name": REAL, "role": "real"}]
        + [{"name": c.name, "role": c.role, "path": str(c.path), "settings": c.settings,
            "reaction_only": c.reaction_only} for c in contenders],
        "notes": notes,
        "protocol": {k: v for k, v in protocol.items() if v is not None},
        "relations": relations,
        "physics": physics,
        "accumulation": table,
        "accumulation_prompts": accumulation_prompts(corpus, plan.accumulation_prompts),
        "motion": motion,
        "reconstruction": reconstruction,
        "speed": speed,
        "examples": examples,
    }  # fmt: skip
    write_json_atomic(req.out / "metrics.json", jsonable(results))
    write_text_atomic(req.out / "report.md", render_markdown(jsonable(results)))
    return req.out / "report.md"
