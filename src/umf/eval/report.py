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

from umf.clean_up import delivered_joints
from umf.data.clip import FPS
from umf.data.corpus import Corpus
from umf.eval import accumulation as A
from umf.eval.contenders import (
    Contender,
    _joints,
    _joints_contacts,
    load_contenders,
    load_evaluators,
    person_one_key,
)
from umf.eval.evaluator import KINDS, MotionTextEvaluator
from umf.eval.markdown import PHYSICS_KEYS, render_markdown
from umf.eval.metrics import mean_ci
from umf.eval.physics import physics_report
from umf.eval.plan import (
    REAL,
    SCENE_FRAMES,
    EvalPlan,
    Log,
    delivered_name,
)
from umf.eval.protocol import ProtocolConfig, corpus_items, score_protocol
from umf.eval.relations import real_scene_joints, relation_accuracy
from umf.io import atomic_path, save_png_atomic, write_json_atomic, write_text_atomic
from umf.pipeline import Scene
from umf.version import __version__


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
    if "any_order" in acc:
        loose = acc["any_order"]
        loose["scene_accuracy_ci"] = proportion_ci(loose["scene_accuracy"], acc["num_scenes"])
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
    save_png_atomic(fig, path)


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


def person_section(corpus: Corpus, contenders: Sequence[Contender], evaluator: Any,
                   plan: EvalPlan, log: Log) -> dict[str, Any]:  # fmt: skip
    """Per-person text matching of every model that takes per-person prompts
    (:mod:`umf.eval.person_matching`); the quick plan scores the first 48 scenes."""
    from umf.eval.person_matching import person_items, person_matching

    models = [c for c in contenders if getattr(c.pipe, "person_prompts", False)]
    if evaluator is None or not models:
        return {}
    items = person_items(corpus, plan.split)
    items = items[:48] if plan.quick else items
    out = {}
    for c in models:
        out[c.name] = person_matching(c.pipe, evaluator, items, plan.seed, log=log)
        log(f"{c.name}: per-person matching top-1 {out[c.name]['top1']:.3f}")
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
    person = person_section(corpus, contenders, evaluators.get("single"), plan, log)
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
        "person_prompts": person,
        "reconstruction": reconstruction,
        "speed": speed,
        "examples": examples,
    }  # fmt: skip
    write_json_atomic(req.out / "metrics.json", jsonable(results))
    write_text_atomic(req.out / "report.md", render_markdown(jsonable(results)))
    return req.out / "report.md"
