"""HumanML3D adapter: the dataset's clips, captions and splits as :class:`MotionClip`.

We cannot ship HumanML3D; users who own it point :func:`load_humanml3d` at its root::

    root/new_joint_vecs/<id>.npy   (T, 263) float
    root/new_joints/<id>.npy       (T, 22, 3) (optional here)
    root/texts/<id>.txt            lines ``caption#tokens#start#end``
    root/train.txt, val.txt, test.txt

Ids starting with ``M`` are the dataset's left/right mirrored copies. Motion is 20 fps.

The 263-d vectors are read and written by :mod:`umf.humanml3d`.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from umf.data.clip import FPS, MotionClip
from umf.errors import UMFError
from umf.humanml3d import HUMANML3D_FPS, VEC_DIM, recover_joints, resample
from umf.skeleton import NUM_JOINTS

Tensor = torch.Tensor

SPLITS = ("train", "val", "test")


# --------------------------------------------------------------------- problems
class SkippedItemWarning(UserWarning):
    """A dataset item was skipped (missing, unreadable or invalid file)."""


def report_skipped(path: Path, reason: str, problems: list[tuple[Path, str]] | None) -> None:
    """Never skip silently: warn (naming the file) and record it when asked."""
    reason = reason.splitlines()[0] if reason else "invalid"
    warnings.warn(f"skipped {path}: {reason}", SkippedItemWarning, stacklevel=2)
    if problems is not None:
        problems.append((path, reason))


def load_array(
    path: Path, trailing: tuple[int, ...], problems: list[tuple[Path, str]] | None
) -> np.ndarray | None:
    """A finite float64 array of shape (T >= 2, *trailing) from ``path``, else report it."""
    if not path.is_file():
        report_skipped(path, "file is missing", problems)
        return None
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        report_skipped(path, f"cannot read .npy ({exc})", problems)
        return None
    if not isinstance(arr, np.ndarray) or not np.issubdtype(arr.dtype, np.number):
        report_skipped(path, "not a numeric array", problems)
        return None
    if arr.ndim != 1 + len(trailing) or arr.shape[1:] != trailing:
        report_skipped(
            path, f"shape {arr.shape}, expected (T, {', '.join(map(str, trailing))})", problems
        )
        return None
    if arr.shape[0] < 2:
        report_skipped(path, f"only {arr.shape[0]} frame(s)", problems)
        return None
    if not np.isfinite(arr).all():
        report_skipped(path, "contains NaN or inf", problems)
        return None
    return arr.astype(np.float64)


_SAFE_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")


def read_splits(root: Path) -> dict[str, list[str]]:
    """Ids listed in each present ``<split>.txt`` (file order, blank lines dropped)."""
    out: dict[str, list[str]] = {}
    for name in SPLITS:
        path = root / f"{name}.txt"
        if path.is_file():
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise UMFError(
                    f"{path}: not a readable UTF-8 split file ({type(exc).__name__})"
                ) from None
            ids = [s.strip() for s in lines if s.strip()]
            bad = [i for i in ids if not _SAFE_ID.fullmatch(i)]
            if bad:  # an id is a file name in the dataset's folders, never a path out of them
                raise UMFError(f"{path}: ids must be plain names, got {bad[0]!r}")
            out[name] = ids
    return out


def select_ids(
    root: Path, available: set[str], splits: dict[str, list[str]], split: str | None
) -> list[str]:
    """Ids to load: one split's list, or everything on disk or listed anywhere."""
    if split is None:
        listed = {i for ids in splits.values() for i in ids}
        return sorted(available | listed)
    if split not in SPLITS:
        raise UMFError(f"unknown split {split!r}: expected one of {', '.join(SPLITS)}")
    if split not in splits:
        raise UMFError(f"split file not found: {root / f'{split}.txt'}")
    return list(dict.fromkeys(splits[split]))


def split_lookup(splits: dict[str, list[str]]) -> dict[str, str]:
    """id -> split (the first split file that lists it wins)."""
    out: dict[str, str] = {}
    for name in SPLITS:
        for item in splits.get(name, []):
            out.setdefault(item, name)
    return out


# --------------------------------------------------------------------- captions
@dataclass(frozen=True)
class Caption:
    """One line of a ``texts/<id>.txt`` file; ``start == end == 0`` means the whole clip."""

    text: str
    start: float = 0.0
    end: float = 0.0

    @property
    def whole(self) -> bool:
        return self.start == 0.0 and self.end == 0.0


def _tag(field: str) -> float:
    """A start/end time; NaN, empty or unparsable counts as 0 (HumanML3D's rule for NaN)."""
    try:
        value = float(field)
    except ValueError:
        return 0.0
    return 0.0 if math.isnan(value) else value


def parse_caption_line(line: str) -> Caption | None:
    """``caption#tokens#start#end`` -> :class:`Caption` (``None`` for a blank caption)."""
    parts = line.strip().split("#")
    text = parts[0].strip()
    if not text:
        return None
    start = _tag(parts[2]) if len(parts) > 2 else 0.0
    end = _tag(parts[3]) if len(parts) > 3 else 0.0
    return Caption(text, start, end)


def group_captions(captions: list[Caption]) -> dict[tuple[float, float], list[str]]:
    """Captions per (start, end) segment in order of first appearance; (0, 0) = whole."""
    out: dict[tuple[float, float], list[str]] = {}
    for cap in captions:
        out.setdefault((cap.start, cap.end), []).append(cap.text)
    return out


# --------------------------------------------------------------------- loader
def _check_layout(root: Path, motion_dir: str) -> None:
    if not root.is_dir():
        raise UMFError(f"HumanML3D root not found: {root}")
    for sub in (motion_dir, "texts"):
        if not (root / sub).is_dir():
            raise UMFError(f"not a HumanML3D root: {root / sub} is missing")


def load_humanml3d(
    root: str | Path,
    split: str | None = None,
    *,
    positions: str = "vecs",
    fps: float = FPS,
    problems: list[tuple[Path, str]] | None = None,
) -> Iterator[MotionClip]:
    """Yield HumanML3D clips as 30 fps :class:`MotionClip` records (P = 1, no rotations).

    Args:
        root: the HumanML3D folder (``new_joint_vecs/``, ``texts/``, split files).
        split: ``"train"``, ``"val"`` or ``"test"`` (its file must exist); ``None`` loads
            every id on disk or listed in a split file.
        positions: ``"vecs"`` recovers joints from ``new_joint_vecs`` (the default);
            ``"joints"`` reads ``new_joints`` instead (the same data, pre-decoded).
        fps: output frame rate (30 for umf).
        problems: if given, every skipped item is appended as ``(path, reason)``.

    Whole-clip captions make clip ``<id>``; captions with a time span make one sub-clip
    ``<id>#<k>`` per distinct span (k = 0, 1, ... in file order), cut at rows
    ``int(start * 20):int(end * 20)`` before resampling. Clips stay in HumanML3D's
    canonical frame. Rotations are ``None``: they must be recomputed after resampling.
    Missing or invalid files are skipped with a :class:`SkippedItemWarning` naming them.

    Raises:
        UMFError: root or a required subfolder is missing, or the split file is.
    """
    root = Path(root)
    if positions not in ("vecs", "joints"):
        raise UMFError(f"positions must be 'vecs' or 'joints', got {positions!r}")
    motion_dir = "new_joint_vecs" if positions == "vecs" else "new_joints"
    _check_layout(root, motion_dir)
    splits = read_splits(root)
    available = {p.stem for p in (root / motion_dir).glob("*.npy")}
    ids = select_ids(root, available, splits, split)
    return _iter_clips(root, motion_dir, ids, split_lookup(splits), fps, problems)


def _iter_clips(
    root: Path,
    motion_dir: str,
    ids: list[str],
    split_of: dict[str, str],
    fps: float,
    problems: list[tuple[Path, str]] | None,
) -> Iterator[MotionClip]:
    for item in ids:
        split = split_of.get(item)
        if split is None and item.startswith("M"):
            split = split_of.get(item[1:])  # a mirror follows its original
        yield from _load_item(root, motion_dir, item, split, fps, problems)


def _read_captions(path: Path, problems: list[tuple[Path, str]] | None) -> list[Caption]:
    if not path.is_file():
        report_skipped(path, "caption file is missing", problems)
        return []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        report_skipped(path, f"cannot read captions ({exc})", problems)
        return []
    caps = []
    for n, line in enumerate(lines, start=1):
        c = parse_caption_line(line)
        if c is None:
            continue
        if not (math.isfinite(c.start) and math.isfinite(c.end)) or c.start < 0 or c.end < 0 \
                or (c.end and c.end <= c.start):  # fmt: skip
            # a negative time would count frames from the clip's end: refused, not guessed
            report_skipped(path, f"line {n}: caption times {c.start:g}-{c.end:g} s are not a "
                           "segment (finite, non-negative, end after start)", problems)  # fmt: skip
            continue
        caps.append(c)
    if not caps:
        report_skipped(path, "no captions", problems)
    return caps


def _load_item(
    root: Path,
    motion_dir: str,
    item: str,
    split: str | None,
    fps: float,
    problems: list[tuple[Path, str]] | None,
) -> list[MotionClip]:
    """All clips (whole + sub-segments) of one id; [] after reporting a problem."""
    path = root / motion_dir / f"{item}.npy"
    trailing = (VEC_DIM,) if motion_dir == "new_joint_vecs" else (NUM_JOINTS, 3)
    arr = load_array(path, trailing, problems)
    if arr is None:
        return []
    text_path = root / "texts" / f"{item}.txt"
    groups = group_captions(_read_captions(text_path, problems))
    if not groups:
        return []
    data = torch.from_numpy(arr)
    joints = recover_joints(data) if motion_dir == "new_joint_vecs" else data
    meta = {"file": str(path), "mirrored": item.startswith("M"), "source_fps": HUMANML3D_FPS}
    clips: list[MotionClip] = []
    segments = [(span, texts) for span, texts in groups.items() if span != (0.0, 0.0)]
    for k, ((start, end), texts) in enumerate(segments):
        part = joints[int(start * HUMANML3D_FPS) : int(end * HUMANML3D_FPS)]
        if part.shape[0] < 2:
            report_skipped(text_path, f"segment {start}-{end} s has < 2 frames", problems)
            continue
        sub = {**meta, "parent": item, "segment": (start, end)}
        clips.append(_clip(f"{item}#{k}", part, texts, split, fps, sub))
    if (0.0, 0.0) in groups:
        clips.insert(0, _clip(item, joints, groups[(0.0, 0.0)], split, fps, meta))
    return clips


def _clip(
    clip_id: str, joints: Tensor, captions: list[str], split: str | None, fps: float, meta: dict
) -> MotionClip:
    out = resample(joints, HUMANML3D_FPS, fps).float().numpy()
    return MotionClip(
        id=clip_id,
        source="humanml3d",
        joints=out[None],
        captions=list(captions),
        fps=fps,
        rotations=None,
        split=split,
        meta=meta,
    )
