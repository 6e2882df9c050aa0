"""The bugs issue 39 named, put back one at a time: does `make test` catch each?

Each mutation is an exact text edit of one source line, made in a scratch copy of the
repository (``src/``, ``tests/``, ``data/``, ``pyproject.toml``); the tests that guard it
(a subset of `make test`'s selection, ``-m "not slow"``) run against the copy, and the
mutation is caught when they fail. The edit must match exactly once, so a refactor that
moves the line fails here loudly instead of testing nothing.

    python scripts/named_mutations.py [--only NAME] [--out results/mutation/named.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

REPO = Path(__file__).resolve().parents[1]


class Mutation(NamedTuple):
    name: str
    path: str
    before: str
    after: str
    tests: tuple[str, ...]


MUTATIONS = (
    Mutation("inverse transform turns velocities the wrong way", "src/umf/representation.py",
             "pos, vel = tf.invert(pos), vel @ rot\n", "pos, vel = tf.invert(pos), vel @ rot.T\n",
             ("tests/test_representation.py",)),
    Mutation("check_int: <= hi becomes < hi", "src/umf/validation.py",
             "if not lo <= int(value) <= hi:", "if not lo <= int(value) < hi:",
             ("tests/test_validation.py", "tests/test_bounds.py")),
    Mutation("--actor-person ignored (always person 1)", "src/umf/cli/generate.py",
             "joints = motion.scene(first, count).joints[actor_person - 1]",
             "joints = motion.scene(first, count).joints[0]", ("tests/test_bounds.py",)),
    Mutation("P-Flow without classifier-free guidance", "src/umf/pipeline.py",
             "guidance=FROM_CONFIG if guidance is None else guidance,  # per stage",
             "guidance=1.0,  # per stage", ("tests/test_bounds.py",)),
    Mutation("GLB bone offsets x 1.0008", "src/umf/exports/gltf.py",
             "t = rest[0] if j == 0 else offsets[j]\n",
             "t = rest[0] if j == 0 else offsets[j] * 1.0008\n",
             ("tests/test_export_glb.py", "tests/test_exports_agree.py")),
    Mutation("kinematics: PINNED_DAMPING = 0", "src/umf/kinematics.py",
             "PINNED_DAMPING = 1e9", "PINNED_DAMPING = 0.0", ("tests/test_kinematics.py",)),
    Mutation("pyramid jump at half its alpha", "src/umf/flows/pyramid.py",
             "alpha=jump_alpha(s_next, config.correlation),",
             "alpha=0.5 * jump_alpha(s_next, config.correlation),",
             ("tests/test_flow_pyramid.py",)),
    Mutation("S-Flow sampling ignores reaction_noise", "src/umf/models/sflow.py",
             "                reaction_noise=self.cfg.reaction_noise,\n",
             "                reaction_noise=0.0,\n",
             ("tests/test_sflow_model.py",)),
    Mutation("random stream chosen by place in the chunk", "src/umf/streams.py",
             "for i in indices]", "for i in range(len(indices))]",
             ("tests/test_hardening.py",)),
)  # fmt: skip


def apply(root: Path, m: Mutation) -> None:
    """Edit ``root / m.path``; a ``before`` that does not occur exactly once is an error."""
    path = root / m.path
    text = path.read_text()
    if text.count(m.before) != 1:
        raise SystemExit(f"error: {m.name}: {m.path} has {text.count(m.before)} copies of "
                         f"{m.before!r}, not 1 (the code moved: update this mutation)")  # fmt: skip
    path.write_text(text.replace(m.before, m.after))


def run(m: Mutation) -> dict:
    with tempfile.TemporaryDirectory(prefix="umf-mutation-") as tmp:
        root = Path(tmp)
        for part in ("src", "tests", "data"):
            shutil.copytree(REPO / part, root / part, ignore=shutil.ignore_patterns("__pycache__"))
        shutil.copy(REPO / "pyproject.toml", root)
        apply(root, m)
        env = {**os.environ, "PYTHONPATH": str(root / "src"), "OMP_NUM_THREADS": "1"}
        cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-m",
               "not slow", *m.tests]  # fmt: skip
        proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
        failed = [ln.split(" ", 1)[1] for ln in proc.stdout.splitlines()
                  if ln.startswith("FAILED ")]  # fmt: skip
        return {"mutation": m.name, "file": m.path, "tests": list(m.tests),
                "caught": proc.returncode != 0, "exit_code": proc.returncode,
                "first_failure": failed[0] if failed else None}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="run the mutations whose name contains this")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    for m in MUTATIONS:
        if args.only and args.only not in m.name:
            continue
        row = run(m)
        rows.append(row)
        verdict = "caught" if row["caught"] else "NOT CAUGHT"
        print(f"{verdict:>10}  {m.name}  ({row['first_failure'] or 'all passed'})", flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=1) + "\n")
    sys.exit(0 if all(r["caught"] for r in rows) else 1)


if __name__ == "__main__":
    main()
