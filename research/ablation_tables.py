"""The paper's Tables 3-5 on our corpus, from the `umf eval` reports of the ablations.

Reads ``OUT/{latent,pyramid,sflow}/metrics.json`` (written by ``research/ablations.sh``),
each variant's training time and VAE reconstruction from its run directory
(``RUN/model`` -> ``RUN/<stage>/metrics.csv``), optionally re-times every model on an
otherwise idle machine (``--time``: the reports' own timings are taken while other jobs
share the CPU), and writes ``OUT/README.md`` (ending with ``OUT/notes.md``, the
hand-written reading, if present) and ``OUT/ablations.png``.

    python research/ablation_tables.py results/ablations [--time] [--run NAME=RUN_DIR]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import tempfile
from pathlib import Path
from typing import Any

# Which stage each table retrains (its training time is reported), and what each variant is.
TABLES = {
    "latent": ("Table 3: latent space (each row its own VAE and flows, one budget)", "all"),
    "pyramid": (
        "Table 4: P-Flow pyramid and step allocation (each row's P-Flow retrained)",
        "pflow",
    ),
    "sflow": ("Table 5: S-Flow components (each row's S-Flow retrained)", "sflow"),
}
WHAT = {
    "multi-token": "16 x 16 latent (16 tokens of width 192 projected to 16): ours",
    "single-token": "1 x 256 latent, no pyramid (one token cannot be halved)",
    "no-latent-adapter": "16 x 192 latent: tokens kept at the encoder's width",
    "p-flow": "ours: pyramid over time, 45 coarse + 5 fine steps",
    "steps-25-25": "same P-Flow, 25 coarse + 25 fine steps",
    "steps-5-5": "same P-Flow, 5 + 5 steps",
    "no-pyramid": "P-Flow trained and sampled at full resolution, 50 steps",
    "grid-pyramid": "pyramid over a 4 x 4 token grid (spatial) instead of time",
    "s-flow": "ours: semi-noise path, context adapter, reconstruction loss",
    "reaction-only": "noise-free reaction path (ARFlow-style), no context half",
    "no-recon-loss": "lambda_recon = 0",
    "no-context-adapter": "context enters S-Flow without the transformer adapter",
    "shared-backbone": "S-Flow reuses (and fine-tunes) the P-Flow transformer",
}


def fmt(x: Any, digits: int = 3) -> str:
    """A report value (``[mean, ci]`` or a number) as ``mean ± ci``."""
    from umf.eval.markdown import _pair
    from umf.eval.markdown import fmt as report_fmt

    return report_fmt(*_pair(x), digits=digits)


def relation(r: dict[str, Any]) -> str:
    return fmt([r["scene_accuracy"], r.get("scene_accuracy_ci")])


def stage_seconds(run: Path, stage: str) -> float | None:
    """Wall seconds of one stage's training: the last time stamp of its metrics.csv."""
    path = run / stage / "metrics.csv"
    if not path.exists():
        return None
    with path.open() as f:
        times = [float(r["time"]) for r in csv.DictReader(f) if r.get("time")]
    return max(times) if times else None


def vae_mpjpe(run: Path | None) -> tuple[float | None, float | None]:
    """The VAE's best validation MPJPE (m) on the corpus's validation split, global
    (``mpjpe_m``, dominated by where the body is) and root-relative (``mpjpe_pose_m``)."""
    path = None if run is None else run / "vae" / "metrics.csv"
    if path is None or not path.exists():
        return None, None
    best: dict[str, float] = {}
    with path.open() as f:
        for r in csv.DictReader(f):
            if r["split"] == "val" and r["name"] in ("mpjpe_m", "mpjpe_pose_m"):
                best[r["name"]] = min(float(r["value"]), best.get(r["name"], float("inf")))
    return best.get("mpjpe_m"), best.get("mpjpe_pose_m")


def run_dir(source: dict[str, Any], runs: dict[str, Path]) -> Path | None:
    if source["name"] in runs:
        return runs[source["name"]]
    path = Path(source["path"])
    return path.parent if path.name == "model" else None


def retime(sources: list[dict[str, Any]], repeats: int) -> dict[str, float]:
    """Seconds per N = 2 scene (4 s, batch 1) for every model, measured in this process."""
    from umf.eval.contenders import Contender
    from umf.eval.report import speed_section
    from umf.pipeline import UMFPipeline

    loaded: dict[str, UMFPipeline] = {}
    out: dict[str, float] = {}
    for s in sources:
        key = os.path.realpath(s["path"])
        if key not in loaded:
            loaded[key] = UMFPipeline.from_pretrained(s["path"])
        c = Contender(s["name"], Path(s["path"]), loaded[key], settings=s.get("settings") or {})
        prompt = "two people bow to each other"
        out[s["name"]] = speed_section(c, prompt, repeats, 0)["seconds_per_scene"]
    return out


def rows_for(
    key: str, m: dict[str, Any], runs: dict[str, Path], times: dict[str, float]
) -> tuple[list[str], list[list[str]]]:
    stage = TABLES[key][1]
    proto = m["protocol"]
    pairs = proto["interaction"]["results"]
    single = proto.get("single", {}).get("results", {})
    header = ["variant", "what changes", "FID ↓", "R-prec. top-3 ↑", "MM-Dist ↓",
              "single FID ↓", "single top-3 ↑", "relations, pairs ↑", "relations, groups ↑",
              "penetration cm, groups ↓", "NFE", "GFLOPs / scene", "s / scene",
              "training min"]  # fmt: skip
    if key == "latent":
        header[2:2] = ["VAE val MPJPE m ↓", "VAE val pose MPJPE cm ↓"]
    rows = [["real data", "test split", *[""] * (len(header) - 2)]]
    real = pairs["real"]
    rows[0][header.index("FID ↓")] = fmt(real["fid"])
    rows[0][header.index("R-prec. top-3 ↑")] = fmt(real["r_precision_top3"])
    rows[0][header.index("MM-Dist ↓")] = fmt(real["mm_dist"])
    if "real" in single:
        rows[0][header.index("single FID ↓")] = fmt(single["real"]["fid"])
        rows[0][header.index("single top-3 ↑")] = fmt(single["real"]["r_precision_top3"])
    for s in m["sources"][1:]:
        name, run = s["name"], run_dir(s, runs)
        g, sg = pairs[name], single.get(name, {})
        speed = m["speed"][name]
        secs = None
        if run is not None:
            stages = ("vae", "pflow", "sflow") if stage == "all" else (stage,)
            parts = [stage_seconds(run, st) for st in stages]
            secs = sum(parts) if all(p is not None for p in parts) else None
        if s.get("settings"):
            secs = 0.0  # the same trained model, sampled differently
        row = [
            name, WHAT.get(name, ""),
            fmt(g["fid"], 1), fmt(g["r_precision_top3"]), fmt(g["mm_dist"]),
            fmt(sg.get("fid"), 1), fmt(sg.get("r_precision_top3")),
            relation(m["relations"]["pairs"][name]),
            relation(m["relations"]["groups"][name]),
            fmt(m["physics"]["groups"][name]["penetration_cm"], 2),
            str(speed["nfe"]), f"{speed['flops'] / 1e9:.2f}",
            f"{times.get(name, speed['seconds_per_scene']):.3f}",
            "—" if secs is None else ("0 (same weights)" if secs == 0 else f"{secs / 60:.1f}"),
        ]  # fmt: skip
        if key == "latent":
            mp, pose = vae_mpjpe(run)
            row[2:2] = ["—" if mp is None else f"{mp:.3f}",
                        "—" if pose is None else f"{100 * pose:.1f}"]  # fmt: skip
        rows.append(row)
    return header, rows


def plot(tables: dict[str, dict[str, Any]], path: Path) -> None:
    """FID and R-precision top-3 per variant, one panel pair per table: one person for the
    P-Flow table (its rows share the S-Flow, which dominates two-person scores), two else."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(tables), figsize=(5 * len(tables), 6.5), squeeze=False)
    for j, (key, m) in enumerate(tables.items()):
        one = key == "pyramid" and "single" in m["protocol"]
        res = m["protocol"]["single" if one else "interaction"]["results"]
        names = [s["name"] for s in m["sources"][1:]]
        who = "one person" if one else "two people"
        panels = (("fid", f"FID ({who}) ↓"), ("r_precision_top3", f"R-precision top-3 ({who}) ↑"))
        for i, (metric, label) in enumerate(panels):
            ax = axes[i][j]
            vals = [res[n][metric][0] for n in names]
            errs = [res[n][metric][1] or 0.0 for n in names]
            ax.bar(range(len(names)), vals, yerr=errs, color="C0", capsize=3)
            if metric == "r_precision_top3":
                ax.axhline(res["real"][metric][0], color="C3", ls="--", label="real data")
                ax.legend(loc="upper right", fontsize=8)
            ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
            ax.set_ylabel(label)
            if i == 0:
                ax.set_title(TABLES[key][0].split(":")[0] + ": " + key)
    fig.tight_layout()
    with tempfile.NamedTemporaryFile(suffix=".png", dir=path.parent, delete=False) as tmp:
        fig.savefig(tmp.name, dpi=110)
    os.replace(tmp.name, path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="results/ablations")
    ap.add_argument("--run", action="append", default=[], help="NAME=RUN_DIR of a model "
                    "not exported into RUN/model (e.g. the bundled one)")  # fmt: skip
    ap.add_argument("--time", action="store_true", help="re-time every model here")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    runs = {n: Path(p) for n, _, p in (r.partition("=") for r in args.run)}
    tables = {k: json.loads((args.out / k / "metrics.json").read_text())
              for k in TABLES if (args.out / k / "metrics.json").exists()}  # fmt: skip
    if not tables:
        raise SystemExit(f"no ablation reports under {args.out}")
    from umf.eval.markdown import md_table

    parts = [
        "# Ablations: the paper's " + ", ".join(TABLES[k][0].split(":")[0] for k in tables)
        + " on the Bandai corpus",
        "",
        "Each table's rows, its first included, retrain only what they vary, all at one budget "
        "(`research/ablations.sh`), so rows compare with each other. "
        "Every number comes from fully generated scenes scored by `umf eval` (two people: the "
        "InterGen protocol with our evaluator, groups of 96; single: P-Flow alone). Mean ± 95% "
        "interval over the replications of each report. Relations: fraction of test scenes "
        "whose every relation check holds (pairs; zero-shot groups of 3-6). s / scene: one "
        "N = 2, 4-s scene at batch 1 on this machine" + (" (re-timed on an idle CPU)."
                                                       if args.time else "."),
        "",
        "![ablations](ablations.png)",
        "",
    ]  # fmt: skip
    for key, m in tables.items():
        times = retime(m["sources"][1:], args.repeats) if args.time else {}
        header, rows = rows_for(key, m, runs, times)
        report = f"Report: [{key}/report.md]({key}/report.md); command: `{m['meta']['command']}`"
        parts += [f"## {TABLES[key][0]}", "", report, "", md_table(header, rows, left=2), ""]
    notes = args.out / "notes.md"  # the reading of the tables, written by hand
    if notes.exists():
        parts += [notes.read_text().strip(), ""]
    plot(tables, args.out / "ablations.png")
    text = "\n".join(parts) + "\n"
    with tempfile.NamedTemporaryFile("w", dir=args.out, delete=False, suffix=".md") as tmp:
        tmp.write(text)
    os.replace(tmp.name, args.out / "README.md")
    print(f"wrote {args.out / 'README.md'} and {args.out / 'ablations.png'}")


if __name__ == "__main__":
    main()
