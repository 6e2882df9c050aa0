"""A model directory that decodes or samples with other options than its source.

Settings that need no training (the VAE's position fusion, guidance, step counts) are
chosen by scoring one trained model at several values on the val split. This writes
such a variant: the same weights (hard links where the file system allows, else copies),
``config.json`` with the ``--set`` options applied and checked, and ``format.json``
named ``--name``, so ``umf eval --variant NAME=DST`` and the reports tell them apart.

    python scripts/model_variant.py SRC DST --set vae.root_fusion=0.001 [--set ...]
        [--name NAME]

The variants of results/umf-small-bandai-20261127 (val split) were written this way.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from umf.config import UMFConfig, set_option
from umf.errors import UMFError
from umf.pipeline import UMFPipeline, check_model_config


def derive_model(src: Path, dst: Path, writers: dict[str, Callable[[Path], None]],
                 name: str | None = None, record: dict | None = None) -> Path:  # fmt: skip
    """Write DST (which must not exist) as SRC with the files ``writers`` names written by
    them (each called with the file's new path) and every other file linked (copied where the
    file system cannot link); ``format.json`` named ``name`` (default DST's) with ``record``
    added. Atomic: built in a temporary directory, checked to load, then renamed."""
    src, dst = Path(src), Path(dst)
    if not (src / "config.json").exists() or not (src / "format.json").exists():
        raise UMFError(f"{src}: not a model directory (no config.json / format.json)")
    if dst.exists():
        raise UMFError(f"{dst} exists; choose a new directory")
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", dir=dst.parent))
    try:
        for f in src.iterdir():
            if f.is_file() and f.name not in writers and f.name != "format.json":
                try:
                    os.link(f, tmp / f.name)
                except OSError:
                    shutil.copy2(f, tmp / f.name)
        for file, write in writers.items():
            write(tmp / file)
        fmt = {**json.loads((src / "format.json").read_text()), **(record or {})}
        fmt["name"] = name or dst.name
        (tmp / "format.json").write_text(json.dumps(fmt, indent=2) + "\n")
        UMFPipeline.from_pretrained(tmp)  # the weights must still fit (no d_model changes)
        tmp.rename(dst)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dst


def write_variant(src: Path, dst: Path, options: list[str], name: str | None = None) -> Path:
    """Write DST (which must not exist) from the model directory SRC and the options."""
    src = Path(src)
    if not (src / "config.json").exists() or not (src / "format.json").exists():
        raise UMFError(f"{src}: not a model directory (no config.json / format.json)")
    cfg = UMFConfig.load_yaml(src / "config.json")
    for option in options:
        cfg = set_option(cfg, option)
    check_model_config(cfg)
    old = json.loads((src / "format.json").read_text()).get("name")
    # a model only named (e.g. a fresh export) is no variant of anything
    record = {"variant_of": {"name": old, "options": list(options)}} if options else None
    text = json.dumps(cfg.to_dict(), indent=2)
    return derive_model(src, dst, {"config.json": lambda path: path.write_text(text)}, name,
                        record)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--set", dest="options", action="append", default=[],
                    help="an option, e.g. vae.root_fusion=0.001 (repeatable)")  # fmt: skip
    ap.add_argument("--name", default=None, help="the variant's name (default: DST's)")
    args = ap.parse_args()
    try:
        out = write_variant(Path(args.src), Path(args.dst), args.options, args.name)
    except UMFError as exc:
        sys.exit(f"error: {exc}")
    print(out)


if __name__ == "__main__":
    main()
