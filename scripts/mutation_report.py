"""The mutation score of `make mutation`: per module, from mutmut's results, with every
surviving mutant listed and either explained as equivalent or left to be killed.

    python scripts/mutation_report.py [--mutants mutants] [--out results/mutation]

Reads the ``*.meta`` files mutmut 3 leaves under ``mutants/`` (one exit code per mutant:
1 the tests failed, the mutant is killed; 0 they passed, it survived; 33 no test covers
it; 36, 24 or -24 it ran out of time, counted as killed as mutmut does; none, not run) and
the diff of each survivor (``mutmut show``). The score is killed / (run - equivalent).
Writes ``README.md`` and ``mutation.json`` under ``--out``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

TIMEOUT_CODES = {36, 24, -24, 152}

# mutants that cannot change behaviour here, and why (name -> reason). Device arguments are
# None on a CPU-only machine anyway; a GPU run of the tests would tell them apart.
EQUIVALENT = {
    "umf.flows.paths.x_expand_time__mutmut_4": "device=None: the default device is the CPU's",
    "umf.flows.paths.x_expand_time__mutmut_7": "device dropped: the default device is the CPU's",
    "umf.flows.paths.x_sample_time__mutmut_10": "device=None: the default device is the CPU's",
    "umf.flows.paths.x_sample_time__mutmut_14": "device dropped: the default device is the CPU's",
    "umf.flows.paths.x_sample_time__mutmut_22": "device=None: the default device is the CPU's",
    "umf.flows.paths.x_sample_time__mutmut_26": "device dropped: the default device is the CPU's",
    "umf.flows.paths.x_flow_matching_loss__mutmut_5": (
        "mask.to(None) keeps the bool mask: bool x float multiplies and sums the same"
    ),
}


def classify(code: int | None) -> str:
    if code is None:
        return "not run"
    if code == 0:
        return "survived"
    if code == 33:
        return "no tests"
    if code in TIMEOUT_CODES:
        return "timeout"
    return "killed"


def module_of(mutant: str) -> str:
    """``umf.flows.paths.x_expand_time__mutmut_4`` -> ``umf.flows.paths``."""
    parts = mutant.split(".")
    while parts and (parts[-1].startswith("x_") or "__mutmut_" in parts[-1]):
        parts.pop()
    return ".".join(parts)


def read_results(mutants: Path) -> dict[str, int | None]:
    codes: dict[str, int | None] = {}
    for meta in sorted(mutants.rglob("*.meta")):
        codes.update(json.loads(meta.read_text()).get("exit_code_by_key", {}))
    return codes


def score(codes: dict[str, int | None], equivalent: dict[str, str] = EQUIVALENT) -> dict:
    """Per module: counts by outcome, equivalents among the survivors, and the score."""
    modules: dict[str, dict] = {}
    for name, code in sorted(codes.items()):
        m = modules.setdefault(module_of(name), {"killed": 0, "survived": 0, "timeout": 0,
                                                 "no tests": 0, "not run": 0,
                                                 "equivalent": 0, "survivors": []})  # fmt: skip
        kind = classify(code)
        if kind == "survived" and name in equivalent:
            m["equivalent"] += 1
        else:
            m[kind] += 1
            if kind in ("survived", "no tests"):
                m["survivors"].append(name)
    for m in modules.values():
        caught = m["killed"] + m["timeout"]
        judged = caught + m["survived"] + m["no tests"]
        m["score"] = round(caught / judged, 4) if judged else None
    return modules


def diff_of(name: str) -> str:
    """The changed line of a mutant (``mutmut show``), or '' when mutmut is not at hand."""
    try:
        out = subprocess.run(["mutmut", "show", name], capture_output=True, text=True,
                             timeout=60).stdout  # fmt: skip
    except (OSError, subprocess.TimeoutExpired):
        return ""
    lines = [ln[1:].strip() for ln in out.splitlines() if ln.startswith("+ ")]
    return lines[-1] if lines else ""


def markdown(modules: dict, diffs: dict[str, str], equivalent: dict[str, str]) -> str:
    lines = ["# Mutation score (`make mutation`)", "",
             "mutmut 3 over the modules of `[tool.mutmut]` in `pyproject.toml`, each mutant "
             "run against the tests that cover it. Score: killed (timeouts included) over "
             "the mutants run, equivalent ones left out.", "",
             "| module | mutants run | killed | timeout | survived | no tests | equivalent "
             "| score |", "|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for name, m in modules.items():
        run = m["killed"] + m["timeout"] + m["survived"] + m["no tests"] + m["equivalent"]
        pct = "—" if m["score"] is None else f"{100 * m['score']:.1f} %"
        lines.append(f"| `{name}` | {run} | {m['killed']} | {m['timeout']} | {m['survived']} "
                     f"| {m['no tests']} | {m['equivalent']} | {pct} |")  # fmt: skip
    survivors = [s for m in modules.values() for s in m["survivors"]]
    lines += ["", f"## Surviving mutants ({len(survivors)})", ""]
    lines += [f"- `{s}`: `{diffs.get(s, '')}`" for s in survivors] or ["None."]
    lines += ["", f"## Equivalent mutants ({len(equivalent)})", ""]
    lines += [f"- `{k}`: `{diffs.get(k, '')}`: {v}" for k, v in equivalent.items()]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutants", type=Path, default=Path("mutants"))
    ap.add_argument("--out", type=Path, default=Path("results/mutation"))
    args = ap.parse_args()
    codes = read_results(args.mutants)
    if not codes:
        sys.exit(f"error: no mutmut results under {args.mutants} (run `make mutation`)")
    modules = score(codes)
    seen = [s for m in modules.values() for s in m["survivors"]]
    equivalent = {k: v for k, v in EQUIVALENT.items() if k in codes}
    diffs = {name: diff_of(name) for name in [*seen, *equivalent]}
    args.out.mkdir(parents=True, exist_ok=True)
    report = {"modules": modules, "equivalent": equivalent, "diffs": diffs}
    (args.out / "mutation.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / "README.md").write_text(markdown(modules, diffs, equivalent))
    for name, m in modules.items():
        print(f"{name}: score {m['score']}, {len(m['survivors'])} surviving")


if __name__ == "__main__":
    main()
