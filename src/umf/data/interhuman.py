"""InterHuman adapter: two-person clips from the dataset's processed files.

We cannot ship InterHuman; users who own it point :func:`load_interhuman` at its root::

    root/motions_processed/person1/<id>.npy   (T, 492)
    root/motions_processed/person2/<id>.npy   (T, 492)
    root/annots/<id>.txt                      descriptions, one per line (3)
    root/train.txt, val.txt, test.txt         ids per split
    root/ignore_list.txt                      ids to leave out (optional)

Each row is 62 joint positions (x, y, z) then 51 joint 6-D rotations; the first 22
positions (columns 0:66) are the SMPL-22 joints, columns 186:312 the 6-D local rotations
of joints 1..21 (first two columns of R, relative to the parent). 30 fps, metres.

Up axis (an assumption, documented and switchable): the processed positions are Z-up.
InterGen's loader converts them with ``p' = M p``, ``M = [[1,0,0],[0,0,1],[0,-1,0]]``
(x' = x, y' = z, z' = -y, a -90 degree turn about +X, det +1) and so does
``up_axis="z"`` (the default). ``up_axis="y"`` takes the positions as they are. Local
rotations of joints 1..21 do not depend on the world frame (a world rotation cancels in
``G_parent^T G_child``), so only the positions are converted; the root rotation is
recovered by :func:`umf.skeleton.inverse_kinematics` from the converted joints. Joints
1..21 stay relative to the dataset's own (SMPL) rest pose, the root to umf's fitted rest
frame: FK with umf offsets reproduces the joints only where those rest poses agree.
Both people stay in the file's shared world frame (adapters do not canonicalise).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from umf.data.clip import FPS, MotionClip
from umf.data.humanml3d import load_array, read_splits, report_skipped, select_ids, split_lookup
from umf.errors import UMFError
from umf.rotations import sixd_to_matrix
from umf.skeleton import NUM_JOINTS, inverse_kinematics

Tensor = torch.Tensor

ROW_DIM = 492
POSITIONS = slice(0, 66)
ROTATIONS = slice(186, 312)
ZUP_TO_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
PEOPLE = ("person1", "person2")


def to_y_up(joints: np.ndarray, up_axis: str) -> np.ndarray:
    """Positions (..., 3) in the file's frame -> umf's Y-up frame."""
    if up_axis == "y":
        return joints
    if up_axis == "z":
        return joints @ ZUP_TO_YUP.T
    raise UMFError(f"up_axis must be 'y' or 'z', got {up_axis!r}")


def split_row(rows: np.ndarray, up_axis: str) -> tuple[np.ndarray, np.ndarray]:
    """(T, 492) -> Y-up joints (T, 22, 3) and 6-D local rotations (T, 21, 6)."""
    joints = rows[:, POSITIONS].reshape(-1, NUM_JOINTS, 3)
    return to_y_up(joints, up_axis), rows[:, ROTATIONS].reshape(-1, NUM_JOINTS - 1, 6)


def person_rotations(joints: Tensor, local6d: Tensor) -> Tensor:
    """Local rotations (T, 22, 3, 3): IK root (this person's fitted offsets) + file's 1..21."""
    root = inverse_kinematics(joints)[:, :1]
    return torch.cat([root, sixd_to_matrix(local6d)], dim=1)


def read_id_list(path: Path) -> set[str]:
    """Ids in an optional one-per-line file (empty when absent)."""
    if not path.is_file():
        return set()
    return {s.strip() for s in path.read_text().splitlines() if s.strip()}


def read_annotations(path: Path, problems: list[tuple[Path, str]] | None) -> list[str]:
    """Non-empty description lines of ``annots/<id>.txt``; [] after reporting a problem."""
    if not path.is_file():
        report_skipped(path, "annotation file is missing", problems)
        return []
    try:
        lines = [s.strip() for s in path.read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        report_skipped(path, f"cannot read annotations ({exc})", problems)
        return []
    captions = [s for s in lines if s]
    if not captions:
        report_skipped(path, "no descriptions", problems)
    return captions


def _check_layout(root: Path) -> None:
    if not root.is_dir():
        raise UMFError(f"InterHuman root not found: {root}")
    for sub in (*(f"motions_processed/{p}" for p in PEOPLE), "annots"):
        if not (root / sub).is_dir():
            raise UMFError(f"not an InterHuman root: {root / sub} is missing")


def load_interhuman(
    root: str | Path,
    split: str | None = None,
    *,
    up_axis: str = "z",
    problems: list[tuple[Path, str]] | None = None,
) -> Iterator[MotionClip]:
    """Yield InterHuman scenes as :class:`MotionClip` records (P = 2, 30 fps, rotations).

    Args:
        root: the InterHuman folder (``motions_processed/``, ``annots/``, split files).
        split: ``"train"``, ``"val"`` or ``"test"`` (its file must exist); ``None`` loads
            every id on disk or listed in a split file.
        up_axis: the files' up axis, ``"z"`` (default, converted) or ``"y"`` (as is).
        problems: if given, every skipped item is appended as ``(path, reason)``.

    Ids in ``ignore_list.txt`` are left out by design (not reported). Missing or invalid
    files are skipped with a :class:`~umf.data.humanml3d.SkippedItemWarning` naming them.

    Raises:
        UMFError: root, a required subfolder or the requested split file is missing, or
            ``up_axis`` is not ``"y"``/``"z"``.
    """
    root = Path(root)
    if up_axis not in ("y", "z"):
        raise UMFError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    _check_layout(root)
    splits = read_splits(root)
    available = {p.stem for p in (root / "motions_processed" / PEOPLE[0]).glob("*.npy")}
    ignored = read_id_list(root / "ignore_list.txt")
    ids = [i for i in select_ids(root, available, splits, split) if i not in ignored]
    return _iter_clips(root, ids, split_lookup(splits), up_axis, problems)


def _iter_clips(
    root: Path,
    ids: list[str],
    split_of: dict[str, str],
    up_axis: str,
    problems: list[tuple[Path, str]] | None,
) -> Iterator[MotionClip]:
    for item in ids:
        clip = _load_item(root, item, split_of.get(item), up_axis, problems)
        if clip is not None:
            yield clip


def _load_item(
    root: Path,
    item: str,
    split: str | None,
    up_axis: str,
    problems: list[tuple[Path, str]] | None,
) -> MotionClip | None:
    paths = [root / "motions_processed" / p / f"{item}.npy" for p in PEOPLE]
    rows = [load_array(p, (ROW_DIM,), problems) for p in paths]
    if rows[0] is None or rows[1] is None:
        return None
    if rows[0].shape[0] != rows[1].shape[0]:
        lengths = f"{rows[0].shape[0]} vs {rows[1].shape[0]}"
        report_skipped(paths[1], f"frame count differs from person1 ({lengths})", problems)
        return None
    captions = read_annotations(root / "annots" / f"{item}.txt", problems)
    if not captions:
        return None
    parts = [split_row(r, up_axis) for r in rows]
    joints = torch.from_numpy(np.stack([j for j, _ in parts]))
    rotations = torch.stack(
        [person_rotations(joints[i], torch.from_numpy(r6)) for i, (_, r6) in enumerate(parts)]
    )
    return MotionClip(
        id=item,
        source="interhuman",
        joints=joints.float().numpy(),
        captions=captions,
        fps=FPS,
        rotations=rotations.float().numpy(),
        split=split,
        meta={"files": [str(p) for p in paths], "up_axis": up_axis},
    )
