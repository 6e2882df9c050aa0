"""The checkpoint directory, the one format every stage saves, resumes and ships.

Layout of a checkpoint directory::

    format.json            {"format": "umf-checkpoint", "version": 1, "modules": [...], ...}
    config.json            the model config (enough to rebuild the modules)
    <name>.safetensors     weights of one module (fp32, or fp16 when exported)
    normalizer.safetensors feature mean/std (optional)
    trainer_state.pt       step, best val, RNG, optimizer, scheduler, EMA (absent in exports)

The directory is the unit of atomicity: it is written into a hidden temporary sibling and
renamed into place, and the previous checkpoint is only removed once the new one is
complete. A crash between the two renames leaves ``.<name>.old-*``, which loading falls
back to and the next save restores, so a readable checkpoint always exists.

``keep_previous`` (training's ``last``) keeps the replaced checkpoint as ``<name>.prev``;
:func:`load_first_good` tries candidates in order and warns when it skips a damaged one,
so a ``last`` corrupted on disk later is not a dead end.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from umf.errors import UMFError
from umf.representation import Normalizer
from umf.version import __version__

FORMAT = "umf-checkpoint"
FORMAT_VERSION = 1
RESERVED = {"normalizer", "format", "config", "trainer_state"}
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")

StateDict = Mapping[str, torch.Tensor]
T = TypeVar("T")


@dataclass
class Checkpoint:
    """What :func:`load_checkpoint` read; ``weights`` holds modules not loaded in place."""

    path: Path
    info: dict[str, Any]
    config: dict[str, Any]
    normalizer: Normalizer | None
    weights: dict[str, dict[str, torch.Tensor]] = field(default_factory=dict)
    state: dict[str, Any] = field(default_factory=dict)
    optimizer: dict[str, Any] | None = None
    scheduler: dict[str, Any] | None = None
    ema: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def step(self) -> int:
        return int(self.state.get("step", self.info.get("step", 0)))


# --------------------------------------------------------------------- save
def save_checkpoint(
    path: str | os.PathLike,
    modules: Mapping[str, nn.Module | StateDict],
    *,
    config: Mapping[str, Any] | None = None,
    normalizer: Normalizer | None = None,
    state: Mapping[str, Any] | None = None,
    optimizer: Mapping[str, Any] | None = None,
    scheduler: Mapping[str, Any] | None = None,
    ema: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
    dtype: torch.dtype | None = None,
    keep_previous: bool = False,
    name: str | None = None,
) -> Path:
    """Write a complete checkpoint directory at ``path`` atomically; returns ``path``.

    ``modules`` maps names to modules or state dicts (e.g. EMA weights). ``dtype`` casts
    floating weights (``torch.float16`` to ship); the normaliser always stays fp32.
    ``trainer_state.pt`` is written when any of state/optimizer/scheduler/ema/extra is given.
    ``keep_previous`` moves the checkpoint it replaces to ``<name>.prev``. ``name`` (a
    model's display name) goes into ``format.json``.
    """
    path = Path(path)
    for module_name in modules:
        _check_name(module_name)
    path.parent.mkdir(parents=True, exist_ok=True)
    recover(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        _chmod_like_plain_dir(tmp)
        _write_contents(tmp, modules, config, normalizer, state, dtype, name)
        trainer = {"state": dict(state or {}), "optimizer": optimizer, "scheduler": scheduler}
        trainer |= {"ema": ema, "extra": dict(extra or {})}
        if state or optimizer or scheduler or ema or extra:
            torch.save(trainer, tmp / "trainer_state.pt")
            _fsync(tmp / "trainer_state.pt")
        _swap_in(tmp, path, previous_path(path) if keep_previous else None)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def _write_contents(
    out: Path,
    modules: Mapping[str, nn.Module | StateDict],
    config: Mapping[str, Any] | None,
    normalizer: Normalizer | None,
    state: Mapping[str, Any] | None,
    dtype: torch.dtype | None,
    model_name: str | None = None,
) -> None:
    for name, module in modules.items():
        _write_module(out / f"{name}.safetensors", name, _tensors(module, dtype))
    if normalizer is not None:
        save_file(
            {"mean": normalizer.mean.float().cpu().contiguous(),
             "std": normalizer.std.float().cpu().contiguous()},
            str(out / "normalizer.safetensors"),
        )  # fmt: skip
        _fsync(out / "normalizer.safetensors")
    info: dict[str, Any] = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "umf_version": __version__,
        "modules": list(modules),
        "dtype": str(dtype or torch.float32).removeprefix("torch."),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    if state and "step" in state:
        info["step"] = int(state["step"])
    if model_name:
        info["name"] = str(model_name)
    _write_json(out / "config.json", dict(config or {}))
    _write_json(out / "format.json", info)  # last: marks the directory complete


def _write_module(path: Path, name: str, tensors: dict[str, torch.Tensor]) -> None:
    save_file(tensors, str(path), metadata={"format": FORMAT, "module": name})
    _fsync(path)


def _tensors(module: nn.Module | StateDict, dtype: torch.dtype | None) -> dict[str, torch.Tensor]:
    """Detached CPU copies (safetensors refuses tied tensors; copies make them distinct)."""
    sd = module.state_dict() if isinstance(module, nn.Module) else module
    out = {}
    for key, t in sd.items():
        t = t.detach()
        if dtype is not None and t.is_floating_point():
            t = t.to(dtype)
        out[key] = t.to("cpu", copy=True).contiguous()
    return out


def _write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2) + "\n", encoding="utf-8")
    _fsync(path)


def _fsync(path: Path) -> None:
    """Flush to disk, with the permissions a plain open() would give (safetensors: 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _chmod_like_plain_dir(path: Path) -> None:
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o777 & ~umask)


def previous_path(path: str | os.PathLike) -> Path:
    """Where ``keep_previous`` keeps the checkpoint a save replaced."""
    path = Path(path)
    return path.parent / f"{path.name}.prev"


def _swap_in(tmp: Path, path: Path, keep: Path | None = None) -> None:
    """Rename ``tmp`` to ``path``, keeping the old directory until the new one is in place
    (and afterwards as ``keep``, when given)."""
    old = None
    if path.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
        os.replace(path, old)  # onto an empty directory: allowed on POSIX
    os.replace(tmp, path)
    if old is not None and keep is not None:
        shutil.rmtree(keep, ignore_errors=True)
        os.replace(old, keep)
    elif old is not None:
        shutil.rmtree(old, ignore_errors=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _olds(path: Path) -> list[Path]:
    found = [p for p in path.parent.glob(f".{path.name}.old-*") if (p / "format.json").exists()]
    return sorted(found, key=lambda p: p.stat().st_mtime)


def recover(path: str | os.PathLike) -> None:
    """Undo an interrupted save: restore a displaced old checkpoint, drop temporaries."""
    path = Path(path)
    if not path.parent.exists():
        return
    olds = _olds(path)
    if not path.exists() and olds:
        os.replace(olds.pop(), path)
    for stale in [*olds, *path.parent.glob(f".{path.name}.tmp-*")]:
        shutil.rmtree(stale, ignore_errors=True)


def _check_name(name: str) -> None:
    if not _NAME.match(name) or name in RESERVED:
        raise UMFError(f"invalid checkpoint module name {name!r}")


# --------------------------------------------------------------------- load
def find_checkpoint(path: str | os.PathLike) -> Path | None:
    """``path`` if it exists, else the complete old copy an interrupted save left, else None."""
    path = Path(path)
    if path.exists():
        return path
    olds = _olds(path) if path.parent.exists() else []
    return olds[-1] if olds else None


def _resolve(path: Path) -> Path:
    found = find_checkpoint(path)
    if found is None:
        raise UMFError(f"{path}: no checkpoint there")
    return found


def read_info(path: str | os.PathLike) -> dict[str, Any]:
    """``format.json`` of a checkpoint, checked for format and version."""
    path = _resolve(Path(path))
    f = path / "format.json"
    if not f.exists():
        raise UMFError(f"{path}: not a umf checkpoint (no format.json)")
    try:
        info = json.loads(f.read_text())
    except (OSError, ValueError) as exc:
        raise UMFError(f"{f}: corrupt checkpoint metadata ({exc})") from exc
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        raise UMFError(f"{path}: not a umf checkpoint (format {info.get('format')!r})")
    if info.get("version") != FORMAT_VERSION:
        raise UMFError(
            f"{path}: checkpoint format v{info.get('version')}, this umf reads v{FORMAT_VERSION}"
        )
    return info


def load_checkpoint(
    path: str | os.PathLike,
    modules: Mapping[str, nn.Module] | None = None,
    *,
    strict: bool = True,
    trainer_state: bool = False,
    map_location: str | torch.device = "cpu",
) -> Checkpoint:
    """Read a checkpoint; load ``modules`` in place (others land in ``Checkpoint.weights``).

    ``strict``: every module key must be present and no unexpected key may remain. Every
    problem is a one-line :class:`UMFError` naming the file or tensor.
    """
    path = _resolve(Path(path))
    info = read_info(path)
    config = _read_json(path / "config.json")
    ck = Checkpoint(path, info, config, _read_normalizer(path))
    wanted = dict(modules or {})
    for name in info.get("modules", []):
        if name not in wanted:
            ck.weights[name] = read_weights(path, name)
    # check every module before loading any, so a failure leaves the modules untouched
    checked = {name: checked_weights(path, name, m, strict=strict) for name, m in wanted.items()}
    for name, module in wanted.items():
        module.load_state_dict(checked[name], strict=False)
    if trainer_state:
        _read_trainer_state(path, ck, map_location)
    return ck


def load_first_good(
    candidates: Sequence[str | os.PathLike],
    load: Callable[[Path], T],
    warn: Callable[[str], None],
) -> T:
    """``load`` the first candidate checkpoint that exists and loads without error.

    Skipping a damaged one is a warning naming it; when none loads, the first error is
    raised (or "no checkpoint" when none exists).
    """
    errors: list[UMFError] = []
    for cand in candidates:
        found = find_checkpoint(cand)
        if found is None:
            continue
        try:
            result = load(found)
        except UMFError as exc:
            errors.append(exc)
            continue
        for err in errors:
            warn(f"warning: skipped a damaged checkpoint ({err}); using {found}")
        return result
    if errors:
        raise errors[0]
    raise UMFError(f"no checkpoint at {', '.join(str(c) for c in candidates)}")


def read_weights(path: str | os.PathLike, name: str) -> dict[str, torch.Tensor]:
    """State dict of one module file, with a clear error when missing or corrupt."""
    f = Path(path) / f"{name}.safetensors"
    if not f.exists():
        raise UMFError(f"{Path(path)}: missing module file {f.name}")
    try:
        return load_file(str(f))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise UMFError(f"{f}: corrupt module file ({_first_line(exc)})") from exc


def checked_weights(
    path: Path,
    name: str,
    module: nn.Module,
    *,
    strict: bool = True,
    may_lack: Callable[[str], bool] | None = None,
) -> dict[str, torch.Tensor]:
    """``<name>.safetensors`` checked against ``module``'s keys and shapes, ready to load.

    Keys for which ``may_lack(key)`` holds may be missing even when ``strict``.
    """
    sd = read_weights(path, name)
    own = module.state_dict()
    missing = [k for k in own if k not in sd and not (may_lack and may_lack(k))]
    unexpected = [k for k in sd if k not in own]
    if strict and (missing or unexpected):
        what = "missing" if missing else "unexpected"
        keys = ", ".join((missing or unexpected)[:3])
        more = " ..." if len(missing or unexpected) > 3 else ""
        raise UMFError(f"{path}: module {name!r} has {what} tensor(s) {keys}{more}")
    for key, t in own.items():  # in the module's order, so the first layer is named first
        if key in sd and sd[key].shape != t.shape:
            raise UMFError(
                f"{path}: tensor {name}.{key} has shape {tuple(sd[key].shape)} in the "
                f"checkpoint but {tuple(t.shape)} in the model"
            )
    return {k: v for k, v in sd.items() if k in own}


def _read_json(f: Path) -> dict[str, Any]:
    if not f.exists():
        raise UMFError(f"{f.parent}: incomplete checkpoint (no {f.name})")
    try:
        return json.loads(f.read_text())
    except (OSError, ValueError) as exc:
        raise UMFError(f"{f}: corrupt JSON ({exc})") from exc


def _read_normalizer(path: Path) -> Normalizer | None:
    f = path / "normalizer.safetensors"
    if not f.exists():
        return None
    try:
        return Normalizer.load(f)
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise UMFError(f"{f}: corrupt normaliser ({_first_line(exc)})") from exc


def _read_trainer_state(path: Path, ck: Checkpoint, map_location: str | torch.device) -> None:
    f = path / "trainer_state.pt"
    if not f.exists():
        raise UMFError(f"{path}: no trainer_state.pt (an exported checkpoint cannot resume)")
    try:
        d = torch.load(f, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged pickle/zip
        raise UMFError(f"{f}: corrupt trainer state ({_first_line(exc)})") from exc
    if not isinstance(d, dict):
        raise UMFError(f"{f}: corrupt trainer state (not a mapping)")
    ck.state = dict(d.get("state") or {})
    ck.optimizer, ck.scheduler, ck.ema = d.get("optimizer"), d.get("scheduler"), d.get("ema")
    ck.extra = dict(d.get("extra") or {})


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


# --------------------------------------------------------------------- export
def export_weights(
    path: str | os.PathLike, out: str | os.PathLike, dtype: torch.dtype = torch.float16
) -> Path:
    """Compact copy for shipping: config, normaliser and weights cast to ``dtype``."""
    src = _resolve(Path(path))
    info = read_info(src)
    weights = {name: read_weights(src, name) for name in info.get("modules", [])}
    return save_checkpoint(
        out,
        weights,
        config=_read_json(src / "config.json"),
        normalizer=_read_normalizer(src),
        dtype=dtype,
    )
