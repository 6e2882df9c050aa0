"""`report.md` of `umf eval`: the sections' results as Markdown tables (numbers with their
95% intervals, real data beside every model)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from umf.eval import accumulation as A
from umf.eval.plan import delivered_name
from umf.eval.relations import INTERCHANGEABLE

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


ANY_ORDER = "scenes passing every check, people the caption leaves open in any order ↑"


def relations_markdown(relations: dict[str, dict[str, Any]]) -> str:
    parts = []
    for name, by_source in relations.items():
        sources = list(by_source)
        first = by_source[sources[0]]
        rows = [
            ["scenes passing every check ↑"]
            + [fmt(a["scene_accuracy"], a["scene_accuracy_ci"]) for a in by_source.values()],
        ]
        if any("any_order" in a for a in by_source.values()):
            rows.append([ANY_ORDER] + [
                fmt(a["any_order"]["scene_accuracy"], a["any_order"].get("scene_accuracy_ci"))
                if "any_order" in a else "—" for a in by_source.values()])  # fmt: skip
        rows += [
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
        if any("any_order" in a for a in by_source.values()):
            rows += [[f"relation: {r}, any order"]
                     + [fmt(a["any_order"]["by_relation"].get(r)) if "any_order" in a else "—"
                        for a in by_source.values()]
                     for r in rels if r in INTERCHANGEABLE]  # fmt: skip
            rows += [[f"kind: {k}, any order"] + [_any_order_kind(a, k) for a in by_source.values()]
                     for k in kinds if _order_matters(by_source.values(), k)]  # fmt: skip
        title = f"**{name}** ({first['num_scenes']} scenes, {first['num_checks']} checks)"
        parts.append(title + "\n\n" + md_table(["", *sources], rows))
    return "\n\n".join(parts)


def _any_order_kind(acc: dict[str, Any], kind: str) -> str:
    """A source's accuracy on checks of ``kind`` read in any order of the people a caption
    leaves open ("—" where it has no such reading)."""
    by_kind = acc.get("any_order", {}).get("by_kind", {})
    return fmt(by_kind[kind]["accuracy"]) if kind in by_kind else "—"


def _order_matters(accs, kind: str) -> bool:
    """Whether reading people in any order changes some source's accuracy on ``kind``:
    only those kinds get an "any order" row."""
    for a in accs:
        loose = a.get("any_order", {}).get("by_kind", {}).get(kind)
        if loose is not None and loose["accuracy"] != a["by_kind"].get(kind, {}).get("accuracy"):
            return True
    return False


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


def person_markdown(section: dict[str, Any]) -> str:
    """Per-person text matching (models with per-person prompts)."""
    rows = [[name, str(v["scenes"]), str(v["people"]), fmt(v["top1"], v["ci95"]),
             fmt(v["chance"])] for name, v in section.items()]  # fmt: skip
    return "\n".join([
        "### Per-person text matching", "",
        "Test scenes whose people play different actions, generated with each person's own "
        "prompt (the first wording of their clip); each person scored by the single-person "
        "evaluator against their own prompt and the others' (`umf.eval.person_matching`).", "",
        md_table(["model", "scenes", "people", "top-1 own prompt ↑", "chance"], rows),
    ])  # fmt: skip


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
    if results.get("person_prompts"):
        out += [person_markdown(results["person_prompts"]), ""]
    out += [
        "## 2. Relation accuracy",
        "",
        "Generated from each test scene's first caption with its number of people and "
        "length; checked against the scene's relation record (`umf.eval.relations`). "
        "A group's record was composed in one order of its people (each next person of a "
        "row on the previous one's left), which its caption does not name; the row \"people "
        'the caption leaves open in any order" reads each group in the order of those '
        'people that passes most checks, and so does a "kind: ..., any order" row, given '
        "for each kind that reading changes.",
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
