"""HumanML3D adapter: the 263-d vector format, its exact inverse, and a clip loader.

We cannot ship HumanML3D; users who own it point :func:`load_humanml3d` at its root::

    root/new_joint_vecs/<id>.npy   (T, 263) float
    root/new_joints/<id>.npy       (T, 22, 3) (optional here)
    root/texts/<id>.txt            lines ``caption#tokens#start#end``
    root/train.txt, val.txt, test.txt

Ids starting with ``M`` are the dataset's left/right mirrored copies. Motion is 20 fps.

Conventions of the 263-d vector (the ones HumanML3D's released files use; ``T`` rows):

=========  ==================================================================
[0:1]      ``theta_vel``: HALF the per-frame turn of the heading quaternion (below)
[1:3]      root XZ velocity ``root[t+1] - root[t]`` rotated by ``r[t+1]``
[3:4]      root height y at frame t
[4:67]     joints 1..21 minus the root's ground point, rotated by ``r[t]``
[67:193]   6-D local rotations of joints 1..21 (first two columns of R)
[193:259]  all 22 joint displacements ``J[t+1] - J[t]`` rotated by ``r[t]``
[259:263]  foot contacts l_ankle, l_foot, r_ankle, r_foot
=========  ==================================================================

The heading quaternion ``r[t]`` (w, x, y, z) is the yaw that turns person's facing
direction onto +Z, i.e. it maps world vectors INTO the heading frame; decoding applies its
conjugate. With ``psi`` the umf yaw of the facing direction (0 facing +Z, positive towards
+X, a right-handed turn about +Y), ``r[t] = (cos(-psi/2), 0, sin(-psi/2), 0)`` and
``theta_vel[t] = -(psi[t+1] - psi[t]) / 2``: a positive value is a turn to the person's
right. Decoding rebuilds ``r[t] = (cos a, 0, sin a, 0)`` with ``a[t] = sum(theta_vel[:t])``,
which assumes ``r[0]`` is the identity: HumanML3D stores every clip canonicalised so the
first frame faces +Z with the root above the origin.
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
import torch.nn.functional as F

from umf.data.clip import FPS, MotionClip
from umf.errors import UMFError
from umf.representation import facing_direction
from umf.rotations import matrix_to_6d, quat_conjugate, quat_mul, quat_rotate, yaw_matrix
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT, NUM_JOINTS, inverse_kinematics

Tensor = torch.Tensor

HUMANML3D_FPS = 20.0
VEC_DIM = 263
ROOT_TURN = slice(0, 1)
ROOT_VEL = slice(1, 3)
ROOT_Y = slice(3, 4)
RIC = slice(4, 67)
ROT = slice(67, 193)
LOCAL_VEL = slice(193, 259)
CONTACT = slice(259, 263)
# HumanML3D's rule: squared per-frame displacement only (its height test is disabled).
CONTACT_VELOCITY_THRESHOLD = 0.002
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


# --------------------------------------------------------------------- heading
def _yaw_quat(angle: Tensor) -> Tensor:
    """Quaternion (w, x, y, z) of a right-handed rotation by ``angle`` (rad) about +Y."""
    half = 0.5 * angle
    zero = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zero, torch.sin(half), zero], dim=-1)


def _gaussian_smooth(x: Tensor, sigma: float) -> Tensor:
    """Gaussian filter of ``x`` (T, C) along time, edges held (HumanML3D's 'nearest')."""
    radius = max(1, int(4.0 * sigma + 0.5))
    k = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    kernel = torch.exp(-0.5 * (k / sigma) ** 2)
    kernel = (kernel / kernel.sum()).expand(x.shape[1], 1, -1)
    padded = F.pad(x.T[None], (radius, radius), mode="replicate")
    return F.conv1d(padded, kernel, groups=x.shape[1])[0].T


def facing_angles(joints: Tensor, sigma: float = 0.0) -> Tensor:
    """Yaw ``psi`` (T,) of the facing direction (hips + shoulders), optionally smoothed.

    ``sigma`` (frames) smooths the facing vectors before taking the angle; HumanML3D's
    own processing used 20. 0 keeps the raw per-frame facing.
    """
    fwd = facing_direction(joints)
    if sigma > 0:
        fwd = _gaussian_smooth(fwd, sigma)
    return torch.atan2(fwd[..., 0], fwd[..., 2])


def canonicalize_first_frame(joints: Tensor, sigma: float = 0.0) -> Tensor:
    """HumanML3D's canonical frame: first-frame root XZ at the origin, facing +Z.

    Heights are left untouched (no floor shift), so decoding reproduces y exactly.
    """
    psi0 = facing_angles(joints, sigma)[0]
    ground = joints[0, 0] * torch.tensor([1.0, 0.0, 1.0], dtype=joints.dtype)
    return (joints - ground) @ yaw_matrix(-psi0).T


# --------------------------------------------------------------------- encode / decode
def _contacts(joints: Tensor, threshold: float) -> Tensor:
    """(T - 1, 4) contacts from squared per-frame foot displacement."""
    idx = list(FOOT_LEFT + FOOT_RIGHT)
    disp2 = ((joints[1:, idx] - joints[:-1, idx]) ** 2).sum(-1)
    return (disp2 < threshold).to(joints.dtype)


def encode_joints(
    joints: Tensor,
    *,
    heading_sigma: float = 0.0,
    contact_threshold: float = CONTACT_VELOCITY_THRESHOLD,
) -> Tensor:
    """Global joints (T, 22, 3) -> HumanML3D vectors (T - 1, 263), see the module docstring.

    The clip is first put in HumanML3D's canonical frame (:func:`canonicalize_first_frame`),
    so ``recover_joints(encode_joints(J))`` equals that canonical copy of ``J[:-1]``.
    Rotations come from :func:`umf.skeleton.inverse_kinematics` (fitted offsets), so they
    are umf's, not numerically HumanML3D's. Computed in float64, returned in J's dtype.
    """
    if joints.ndim != 3 or tuple(joints.shape[1:]) != (NUM_JOINTS, 3):
        raise ValueError(f"expected joints (T, 22, 3), got {tuple(joints.shape)}")
    if joints.shape[0] < 2:
        raise ValueError("need at least 2 frames")
    j = canonicalize_first_frame(joints.double(), heading_sigma)
    n = j.shape[0] - 1
    q = _yaw_quat(-facing_angles(j, heading_sigma))  # (T, 4): facing -> +Z
    rel = quat_mul(q[1:], quat_conjugate(q[:-1]))
    rel = torch.where(rel[..., :1] < 0, -rel, rel)  # shortest turn, also across +-180 deg
    turn = torch.atan2(rel[..., 2], rel[..., 0])  # half the per-frame turn
    root = j[:, 0]
    root_vel = quat_rotate(q[1:], root[1:] - root[:-1])[:, [0, 2]]
    ground = root * torch.tensor([1.0, 0.0, 1.0], dtype=j.dtype)
    q_joints = q[:, None].expand(-1, NUM_JOINTS - 1, -1)
    ric = quat_rotate(q_joints, j[:, 1:] - ground[:, None])
    rot = matrix_to_6d(inverse_kinematics(j)[:, 1:])
    local_vel = quat_rotate(q[:-1, None].expand(-1, NUM_JOINTS, -1), j[1:] - j[:-1])
    out = torch.cat(
        [
            turn[:, None],
            root_vel,
            root[:-1, 1:2],
            ric[:-1].reshape(n, 63),
            rot[:-1].reshape(n, 126),
            local_vel.reshape(n, 66),
            _contacts(j, contact_threshold),
        ],
        dim=-1,
    )
    return out.to(joints.dtype)


def recover_root(vecs: Tensor) -> tuple[Tensor, Tensor]:
    """Heading quaternions (..., T, 4) and root positions (..., T, 3) from (..., T, 263).

    ``a[t] = sum(theta_vel[:t])`` (frame 0: 0), ``r[t] = (cos a, 0, sin a, 0)``; root XZ at
    t is the sum of the stored velocities of rows < t, each rotated back by ``conj(r)`` of
    the frame it ends in. Computed in float64.
    """
    v = vecs.double()
    turn = v[..., 0]
    angle = torch.cat([torch.zeros_like(turn[..., :1]), turn[..., :-1]], dim=-1).cumsum(-1)
    zero = torch.zeros_like(angle)
    q = torch.stack([torch.cos(angle), zero, torch.sin(angle), zero], dim=-1)
    vel = torch.stack([v[..., :-1, 1], zero[..., 1:], v[..., :-1, 2]], dim=-1)
    vel = torch.cat([torch.zeros_like(vel[..., :1, :]), vel], dim=-2)
    xz = quat_rotate(quat_conjugate(q), vel).cumsum(-2)
    root = torch.stack([xz[..., 0], v[..., 3], xz[..., 2]], dim=-1)
    return q, root


def recover_joints(vecs: Tensor) -> Tensor:
    """HumanML3D vectors (..., T, 263) -> global joints (..., T, 22, 3) in vecs' dtype.

    Un-rotates the heading-aligned positions by ``conj(r[t])`` and adds the root XZ.
    """
    if vecs.shape[-1] != VEC_DIM:
        raise ValueError(f"expected (..., T, {VEC_DIM}) vectors, got {tuple(vecs.shape)}")
    q, root = recover_root(vecs)
    ric = vecs.double()[..., RIC].reshape(*vecs.shape[:-1], NUM_JOINTS - 1, 3)
    q_inv = quat_conjugate(q)[..., None, :].expand(*ric.shape[:-1], 4)
    ground = root * torch.tensor([1.0, 0.0, 1.0], dtype=root.dtype)
    joints = quat_rotate(q_inv, ric) + ground[..., None, :]
    return torch.cat([root[..., None, :], joints], dim=-2).to(vecs.dtype)


# --------------------------------------------------------------------- resampling
def resampled_length(num_frames: int, src_fps: float, dst_fps: float) -> int:
    """Frames of the ``dst_fps`` grid ``k / dst_fps`` inside ``[0, (T - 1) / src_fps]``."""
    if num_frames < 2:
        return num_frames
    return math.floor((num_frames - 1) * dst_fps / src_fps + 1e-9) + 1


def resample(x: Tensor, src_fps: float, dst_fps: float) -> Tensor:
    """Linear interpolation along dim 0 onto the exact time grid ``k / dst_fps``.

    The grid never extrapolates past the last source frame: 20 -> 30 fps gives
    ``floor(1.5 (T - 1)) + 1`` frames, the same duration when T is odd and 1/60 s shorter
    when T is even. Positions that are linear in time stay exact.
    """
    num = x.shape[0]
    if num < 2 or src_fps == dst_fps:
        return x.clone()
    steps = torch.arange(resampled_length(num, src_fps, dst_fps), dtype=torch.float64)
    pos = steps * src_fps / dst_fps  # source frame index (multiply first: exact grid hits)
    i0 = pos.floor().long().clamp(max=num - 2)
    w = (pos - i0).to(x.dtype).reshape(-1, *([1] * (x.ndim - 1)))
    return x[i0] * (1.0 - w) + x[i0 + 1] * w


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
