"""A model whose flow weights lie between a model's and its fine-tune's (weight interpolation).

Fine-tuning a released flow on a few actions teaches them but moves everything else a
little too (results/umf-small-bandai-20261217: a jump learnt, the single-person R-precision
0.007 lower). Averaging the two weight sets, ``(1 - alpha) * base + alpha * tuned`` per
tensor (as in robust fine-tuning by weight-space ensembling, WiSE-FT), often keeps most of
what was taught and most of what was known: the fine-tune starts from the base, so the two
lie in one basin and the line between them stays low in loss.

    python scripts/interpolate_weights.py BASE TUNED DST --alpha 0.5 [--module pflow]
        [--name NAME]

BASE and TUNED are model directories of the same architecture (TUNED exported by
``umf train finetune --from BASE``); DST is BASE with ``MODULE.safetensors`` replaced, and
``format.json`` named ``--name`` with an ``interpolated`` record (both names, alpha, module).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from umf.errors import UMFError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from model_variant import derive_model

MODULES = ("vae", "pflow", "sflow")


def interpolate(base: dict[str, torch.Tensor], tuned: dict[str, torch.Tensor],
                alpha: float) -> dict[str, torch.Tensor]:  # fmt: skip
    """``(1 - alpha) * base + alpha * tuned`` for every tensor (in float32, stored in the
    base's dtype); the two must hold the same names and shapes."""
    if set(base) != set(tuned):
        raise UMFError(f"the two weight sets differ in {sorted(set(base) ^ set(tuned))[:3]}")
    out = {}
    for k, a in base.items():
        b = tuned[k]
        if a.shape != b.shape:
            raise UMFError(f"{k}: {tuple(a.shape)} against {tuple(b.shape)}")
        mixed = torch.lerp(a.float(), b.float(), alpha) if a.is_floating_point() else a
        out[k] = mixed.to(a.dtype).contiguous()
    return out


def _read(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    with safe_open(str(path), "pt") as f:
        return {k: f.get_tensor(k) for k in f.keys()}, f.metadata() or {}


def write_interpolated(base: Path, tuned: Path, dst: Path, alpha: float, module: str = "pflow",
                       name: str | None = None) -> Path:  # fmt: skip
    """Write DST (which must not exist): BASE with ``module``'s weights interpolated."""
    base, tuned, dst = Path(base), Path(tuned), Path(dst)
    if module not in MODULES:
        raise UMFError(f"--module must be one of {', '.join(MODULES)}, got {module!r}")
    if not 0.0 <= alpha <= 1.0:
        raise UMFError(f"--alpha must lie in [0, 1], got {alpha}")
    for d in (base, tuned):
        if not (d / f"{module}.safetensors").exists() or not (d / "format.json").exists():
            raise UMFError(f"{d}: not a model directory with {module}.safetensors")
    a, meta = _read(base / f"{module}.safetensors")
    mixed = interpolate(a, _read(tuned / f"{module}.safetensors")[0], alpha)
    names = [json.loads((d / "format.json").read_text()).get("name") for d in (base, tuned)]
    record = {"interpolated": {"base": names[0], "tuned": names[1], "alpha": alpha,
                               "module": module}}  # fmt: skip
    write = lambda path: save_file(mixed, str(path), metadata=meta)  # noqa: E731
    return derive_model(base, dst, {f"{module}.safetensors": write}, name, record)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base")
    ap.add_argument("tuned")
    ap.add_argument("dst")
    ap.add_argument("--alpha", type=float, required=True, help="0: the base, 1: the fine-tune")
    ap.add_argument("--module", default="pflow", help="vae, pflow or sflow (default pflow)")
    ap.add_argument("--name", default=None, help="the model's name (default: DST's)")
    args = ap.parse_args()
    try:
        out = write_interpolated(Path(args.base), Path(args.tuned), Path(args.dst), args.alpha,
                                 args.module, args.name)  # fmt: skip
    except UMFError as exc:
        sys.exit(f"error: {exc}")
    print(out)


if __name__ == "__main__":
    main()
