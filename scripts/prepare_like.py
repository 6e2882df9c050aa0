"""Prepare a corpus again from the sources another corpus's manifest records, with its
options, changing only the number of composed train scenes:

    python scripts/prepare_like.py CORPUS OUT [--train-scenes N]

What ``scripts/reproduce_bundled.py`` runs to rebuild the larger corpus a later stage of the
bundled model trained on (results/umf-small-bandai-20261204c: 6,000 train scenes where
``make corpus`` composes 3,000). Relative source paths are read as the manifest wrote them:
relative to where ``umf data prepare`` ran (the repository root, for ``make corpus``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

KINDS = {"bandai": "--bandai", "humanml3d": "--humanml3d", "interhuman": "--interhuman"}


def prepare_command(manifest: dict, out: Path, train_scenes: int | None) -> list[str]:
    """The ``umf data prepare`` command that rebuilds the manifest's corpus into ``out``."""
    cfg = manifest["config"]
    cmd = [sys.executable, "-m", "umf", "data", "prepare", "--out", str(out),
           "--seed", str(cfg["seed"]),
           "--train-scenes", str(cfg["train_scenes"] if train_scenes is None else train_scenes),
           "--val-scenes", str(cfg["val_scenes"]), "--test-scenes", str(cfg["test_scenes"]),
           "--test-groups", str(cfg["test_groups"])]  # fmt: skip
    for source in manifest["sources"]:
        name, path = source["name"], source["path"]
        flag = "--mocap" if name.startswith("mocap-") else KINDS.get(name)
        if flag is None:
            raise SystemExit(f"error: source {name!r} of the manifest: no prepare option for it")
        if not Path(path).exists():
            raise SystemExit(f"error: source {name!r} of the manifest is gone: {path}")
        cmd += [flag, path]
    return cmd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--train-scenes", type=int, default=None)
    args = ap.parse_args()
    try:
        manifest = json.loads((args.corpus / "manifest.json").read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"error: {args.corpus}: no readable manifest.json ({exc})") from None
    sys.exit(subprocess.run(prepare_command(manifest, args.out, args.train_scenes)).returncode)


if __name__ == "__main__":
    main()
