"""BVH motion files: a strict, fast reader, batched forward kinematics and a writer.

Conventions (the BVH format's, shared with :mod:`umf.rotations`):

- rotation channels are intrinsic Euler angles in degrees, applied in the order listed,
  so ``Zrotation Xrotation Yrotation`` means ``R = Rz @ Rx @ Ry``;
- a joint's local translation is its OFFSET, except that each position channel (on the
  root or on any other joint) replaces the matching OFFSET component for that frame;
- ``R_j = R_parent @ R_local`` and ``p_j = p_parent + R_parent @ t_local``.

Units are the file's own (the Bandai corpus uses centimetres, umf metres). The motion
block is parsed by numpy in one call, so a whole corpus loads in seconds.
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
import torch

from umf.errors import UMFError
from umf.io import atomic_path
from umf.rotations import matrix_to_euler
from umf.skeleton import JOINT_NAMES, PARENTS

__all__ = [
    "BVH",
    "chain_transforms",
    "forward_kinematics",
    "local_transforms",
    "parse_bvh",
    "read_bvh",
    "write_bvh",
    "write_smpl22_bvh",
]

ArrayLike = np.ndarray | torch.Tensor | Sequence

_POSITIONS = ("Xposition", "Yposition", "Zposition")
_ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")
_CANONICAL = {c.lower(): c for c in _POSITIONS + _ROTATIONS}
_KEYWORDS = frozenset({"ROOT", "JOINT", "End", "OFFSET", "CHANNELS", "{", "}", "MOTION"})
_MOTION_RE = re.compile(r"^[ \t]*MOTION[ \t]*$", re.MULTILINE)
_FRAMES_RE = re.compile(
    r"\s*Frames\s*:\s*(\S+)\s+Frame\s+Time\s*:\s*(\S+)[ \t]*(?:\n|$)", re.IGNORECASE
)
_ROW_FORMAT = "%.7f"  # 0.1 micrometre: the files agree with the scene to well under 0.002 mm
MAX_FRAMES = 1_000_000  # a bound on what a file may make the reader allocate
MAX_JOINTS = 1_000


@dataclass
class BVH:
    """One BVH file, as stored: joints in file (depth-first) order, raw channel values.

    Attributes:
        names: joint names.
        parents: parent index of each joint, -1 for a root; ``parents[j] < j``.
        offsets: (J, 3) float64 OFFSET of each joint from its parent.
        channels: channel names of each joint, in file order (canonical spelling).
        motion: (F, C) float64 channel values, C = total number of channels.
        frame_time: seconds per frame, as written in the file.
        end_sites: joint index -> (3,) End Site offset, for joints that have one.
        source: where it was read from, for error messages.
    """

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[list[str]]
    motion: np.ndarray
    frame_time: float
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)
    source: str = "<string>"

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time if self.frame_time > 0 else float("nan")

    def index(self, name: str) -> int:
        """Index of joint ``name``; a missing joint is a data error, hence UMFError."""
        try:
            return self.names.index(name)
        except ValueError:
            raise UMFError(f"{self.source}: no joint named {name!r}") from None


# --------------------------------------------------------------------- reading
def read_bvh(source: str | os.PathLike | IO) -> BVH:
    """Read a BVH file from a path, an open file (text or binary) or the BVH text itself.

    Any malformed or truncated input raises :class:`UMFError` naming the file.
    """
    text, label = _load_text(source)
    return parse_bvh(text, label)


def _load_text(source: str | os.PathLike | IO) -> tuple[str, str]:
    """The text of ``source`` and a label for error messages."""
    if hasattr(source, "read"):
        data = source.read()  # type: ignore[union-attr]
        label = str(getattr(source, "name", "<stream>"))
        return (
            data.decode("utf-8-sig", errors="replace") if isinstance(data, bytes) else data
        ), label
    if isinstance(source, str) and ("\n" in source or source.lstrip().startswith("HIERARCHY")):
        return source, "<string>"
    try:
        data = Path(source).read_bytes()
    except OSError as exc:
        raise UMFError(f"{source}: cannot read BVH file ({exc.strerror or exc})") from None
    return data.decode("utf-8-sig", errors="replace"), str(source)


def parse_bvh(text: str, label: str = "<string>") -> BVH:
    """Parse BVH text; ``label`` names the source in error messages."""
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    found = _MOTION_RE.search(text)
    if found is None:
        raise _error(label, "no MOTION section (truncated or not a BVH file)")
    tokens = _Tokens(text[: found.start()], label)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(tokens)
    if len(names) > MAX_JOINTS:
        raise _error(label, f"{len(names)} joints; umf reads at most {MAX_JOINTS}")
    num_channels = sum(len(c) for c in channels)
    motion, frame_time = _parse_motion(text, found.end(), num_channels, label)
    return BVH(names, parents, offsets, channels, motion, frame_time, end_sites, label)


def _error(label: str, message: str) -> UMFError:
    return UMFError(f"{label}: {' '.join(message.split())}")


class _Tokens:
    """Whitespace-separated words of the HIERARCHY, remembering where each one starts.

    Layout (tabs, spaces, braces on their own line or not) then does not matter, and
    errors can still point at a line.
    """

    def __init__(self, text: str, label: str) -> None:
        found = list(re.finditer(r"\S+", text))
        self.words = [m.group() for m in found]
        self.starts = [m.start() for m in found]
        self.text = text
        self.label = label

    def __len__(self) -> int:
        return len(self.words)

    def get(self, start: int, stop: int) -> list[str]:
        return self.words[start:stop]

    def error(self, i: int, message: str) -> UMFError:
        pos = self.starts[min(i, len(self.starts) - 1)] if self.starts else 0
        return _error(self.label, f"line {self.text.count(chr(10), 0, pos) + 1}: {message}")


def _parse_hierarchy(
    tk: _Tokens,
) -> tuple[list[str], list[int], np.ndarray, list[list[str]], dict[int, np.ndarray]]:
    """Walk the HIERARCHY words: ROOT/JOINT blocks with OFFSET, CHANNELS and End Site."""
    if tk.get(0, 1) != ["HIERARCHY"]:
        raise tk.error(0, "does not start with HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray | None] = []
    channels: list[list[str]] = []
    end_sites: dict[int, np.ndarray] = {}
    stack: list[int] = []  # currently open joint blocks
    i = 1
    while i < len(tk):
        word = tk.words[i]
        joint = stack[-1] if stack else -1
        if word in ("ROOT", "JOINT") and (word == "ROOT") != bool(stack):
            name, i = _read_name(tk, i + 1)
            names.append(name)
            parents.append(joint)
            offsets.append(None)
            channels.append([])
            stack.append(len(names) - 1)
        elif word == "OFFSET" and stack:
            offsets[joint] = _read_floats(tk, i + 1, f"OFFSET of {names[joint]}")
            i += 4
        elif word == "CHANNELS" and stack:
            channels[joint], i = _read_channels(tk, i + 1, names[joint])
        elif word == "End" and stack:
            if tk.get(i + 1, i + 4) != ["Site", "{", "OFFSET"] or tk.get(i + 7, i + 8) != ["}"]:
                raise tk.error(i, f"malformed End Site in joint {names[joint]}")
            if joint in end_sites:
                raise tk.error(i, f"joint {names[joint]} has two End Sites")
            end_sites[joint] = _read_floats(tk, i + 4, f"End Site of {names[joint]}")
            i += 8
        elif word == "}" and stack:
            stack.pop()
            i += 1
        else:
            raise tk.error(i, f"unexpected {word!r} in HIERARCHY")
    if stack:
        raise tk.error(len(tk), f"joint {names[stack[-1]]} is not closed before MOTION")
    if not names:
        raise tk.error(len(tk), "HIERARCHY has no ROOT")
    for name, offset in zip(names, offsets, strict=True):
        if offset is None:
            raise _error(tk.label, f"joint {name} has no OFFSET")
    return names, parents, np.stack(offsets).reshape(-1, 3), channels, end_sites  # type: ignore[arg-type]


def _read_name(tk: _Tokens, i: int) -> tuple[str, int]:
    """A joint name runs up to the opening brace (names with spaces are kept whole)."""
    start = i
    while i < len(tk) and tk.words[i] not in _KEYWORDS:
        i += 1
    if i == start or tk.get(i, i + 1) != ["{"]:
        raise tk.error(start, "expected a joint name followed by '{'")
    return " ".join(tk.get(start, i)), i + 1


def _read_floats(tk: _Tokens, i: int, what: str) -> np.ndarray:
    words = tk.get(i, i + 3)
    try:
        values = np.array([float(w) for w in words], dtype=np.float64)
    except ValueError:
        raise tk.error(i, f"{what} is not numeric: {' '.join(words)}") from None
    if len(values) != 3 or not np.isfinite(values).all():
        raise tk.error(i, f"{what} needs 3 finite numbers")
    return values


def _read_channels(tk: _Tokens, i: int, joint: str) -> tuple[list[str], int]:
    try:
        count = int(tk.words[i])
    except (ValueError, IndexError):
        raise tk.error(i, f"CHANNELS of {joint} has no valid count") from None
    raw = tk.get(i + 1, i + 1 + max(count, 0))
    if count < 0 or len(raw) != count:
        raise tk.error(i, f"CHANNELS of {joint} does not list {count} names")
    found: list[str] = []
    for word in raw:
        if word.lower() not in _CANONICAL:
            raise tk.error(i, f"unknown channel {word!r} on joint {joint}")
        found.append(_CANONICAL[word.lower()])
    if len(set(found)) != count:
        raise tk.error(i, f"repeated channel on joint {joint}: {' '.join(raw)}")
    return found, i + 1 + count


def _parse_motion(text: str, start: int, num_channels: int, label: str) -> tuple[np.ndarray, float]:
    """Frames header plus one numpy call for the values; the slow path only explains errors."""
    header = _FRAMES_RE.match(text, start)
    if header is None:
        raise _error(label, "MOTION is not followed by 'Frames:' and 'Frame Time:'")
    try:
        declared = int(header.group(1))
        frame_time = float(header.group(2))
    except ValueError:
        raise _error(
            label, f"bad Frames/Frame Time values {header.group(1)!r}, {header.group(2)!r}"
        ) from None
    if declared < 0 or not np.isfinite(frame_time) or frame_time < 0:
        raise _error(label, f"bad Frames/Frame Time values {declared}, {frame_time}")
    data = text[header.end() :]
    if declared > MAX_FRAMES:
        raise _error(label, f"declares {declared} frames; umf reads at most {MAX_FRAMES:,} "
                     "(about 9 hours at 30 fps): cut the file")  # fmt: skip
    if num_channels == 0:  # nothing to read per frame: a frame count alone is no motion
        raise _error(label, "no CHANNELS in the hierarchy: the file holds no motion")
    if not data.strip():
        motion = np.zeros((0, num_channels))
    else:
        try:
            motion = np.loadtxt(io.StringIO(data), dtype=np.float64, ndmin=2, comments=None)
        except ValueError:
            motion = None
        if motion is None or motion.shape[1] != num_channels:
            first_line = text.count("\n", 0, header.end()) + 1
            raise _error(label, _explain_motion_error(data, num_channels, first_line))
    if motion.shape[0] != declared:
        raise _error(label, f"has {motion.shape[0]} frames but the header declares {declared}")
    if not np.isfinite(motion).all():
        raise _error(label, "motion data contains NaN or infinity")
    return motion, frame_time


def _explain_motion_error(data: str, num_channels: int, first_line: int) -> str:
    """Locate the first bad frame (Python loop, run only once a file failed to parse)."""
    frame = 0
    for k, line in enumerate(data.split("\n")):
        values = line.split()
        if not values:
            continue
        frame += 1
        where = f"frame {frame} (line {first_line + k})"
        if len(values) != num_channels:
            return f"{where} has {len(values)} values, expected {num_channels}"
        for value in values:
            try:
                float(value)
            except ValueError:
                return f"{where} has a non-numeric value {value!r}"
    return "unreadable motion data"


# --------------------------------------------------------------------- kinematics
def _channel_columns(channels: list[list[str]]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per joint: motion column of X/Y/Z position, of the 3 rotation slots, and the order.

    Missing channels point at column C (a zero column appended by the caller); joints
    with fewer than 3 rotations get the absent axes appended with angle 0.
    """
    num_channels = sum(len(c) for c in channels)
    pos_cols = np.full((len(channels), 3), num_channels)
    rot_cols = np.full((len(channels), 3), num_channels)
    orders: list[str] = []
    start = 0
    for j, chans in enumerate(channels):
        order = ""
        for k, name in enumerate(chans):
            if name in _POSITIONS:
                pos_cols[j, _POSITIONS.index(name)] = start + k
            else:
                rot_cols[j, len(order)] = start + k
                order += name[0]
        orders.append(order + "".join(a for a in "XYZ" if a not in order))
        start += len(chans)
    return pos_cols, rot_cols, orders


def local_transforms(bvh: BVH) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (F, J, 3, 3) and translations (F, J, 3), float64, all frames at once."""
    pos_cols, rot_cols, orders = _channel_columns(bvh.channels)
    values = np.concatenate([bvh.motion, np.zeros((bvh.num_frames, 1))], axis=1)
    trans = np.where(pos_cols < bvh.motion.shape[1], values[:, pos_cols], bvh.offsets)
    angles = values[:, rot_cols]  # (F, J, 3)
    rot = np.empty((bvh.num_frames, bvh.num_joints, 3, 3))
    for order in set(orders):  # one batched call per distinct rotation order
        idx = [j for j, o in enumerate(orders) if o == order]
        rot[:, idx] = _euler_to_matrix(angles[:, idx], order)
    return rot, trans


def _euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """:func:`umf.rotations.euler_to_matrix` in numpy float64 (same convention).

    On arrays this small torch's thread pool costs more than the arithmetic: reading the
    Bandai corpus plus FK took 245 s through torch (2 threads) and 19 s through numpy.
    """
    rad = np.deg2rad(angles_deg)
    cos, sin = np.cos(rad), np.sin(rad)
    out = np.broadcast_to(np.eye(3), (*rad.shape[:-1], 3, 3))
    for i, axis in enumerate(order.upper()):
        a = "XYZ".index(axis)
        b, d = (a + 1) % 3, (a + 2) % 3  # the plane rotated about axis a
        m = np.zeros((*rad.shape[:-1], 3, 3))
        m[..., a, a] = 1.0
        m[..., b, b] = m[..., d, d] = cos[..., i]
        m[..., b, d] = -sin[..., i]
        m[..., d, b] = sin[..., i]
        out = out @ m
    return out


def forward_kinematics(bvh: BVH) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions (F, J, 3) and rotations (F, J, 3, 3), float64, file units."""
    rot, trans = local_transforms(bvh)
    return chain_transforms(rot, trans, bvh.parents)


def chain_transforms(
    rot: np.ndarray, trans: np.ndarray, parents: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Compose local transforms down the tree (needs ``parents[j] < j``); loops over joints."""
    glob_rot = np.empty_like(rot)
    glob_pos = np.empty_like(trans)
    for j, p in enumerate(parents):
        if p < 0:
            glob_rot[:, j], glob_pos[:, j] = rot[:, j], trans[:, j]
        else:
            glob_rot[:, j] = glob_rot[:, p] @ rot[:, j]
            glob_pos[:, j] = glob_pos[:, p] + (glob_rot[:, p] @ trans[:, j, :, None])[..., 0]
    return glob_pos, glob_rot


# --------------------------------------------------------------------- writing
def write_bvh(
    path: str | os.PathLike,
    names: Sequence[str],
    parents: Sequence[int],
    offsets: ArrayLike,
    local_rot: ArrayLike,
    root_pos: ArrayLike,
    frame_time: float,
    order: str = "ZXY",
    end_sites: Mapping[int, ArrayLike] | None = None,
) -> None:
    """Write a BVH file atomically (a failure leaves nothing under ``path``).

    The root gets 6 channels (position, then rotation in ``order``), every other joint 3
    rotation channels; leaves get an End Site (given, or half their own offset, i.e. along
    the bone into them). Joints are written depth-first, so a reader may see them in a
    different order than ``names``: match by name. Lengths are written in the caller's
    units (umf: metres; most BVH tools expect centimetres and offer an import scale).

    Args:
        names, parents: the skeleton; exactly one root (parent -1).
        offsets: (J, 3) rest offset of each joint from its parent.
        local_rot: (F, J, 3, 3) local rotation matrices (root: global orientation).
        root_pos: (F, 3) root position per frame.
        frame_time: seconds per frame.
        order: rotation channel order, intrinsic (``"ZXY"``: ``R = Rz @ Rx @ Ry``).
        end_sites: optional joint index -> (3,) End Site offset for leaf joints.
    """
    rot, pos, off = _as_float64(local_rot), _as_float64(root_pos), _as_float64(offsets)
    names, parents = list(names), [int(p) for p in parents]
    order = order.upper()
    _check_writer_inputs(path, names, parents, off, rot, pos, frame_time, order)
    children = [[c for c, p in enumerate(parents) if p == j] for j in range(len(names))]
    dfs = _depth_first(children, parents.index(-1))
    if len(dfs) != len(names):
        raise UMFError(f"{path}: parents do not form one tree")
    sites = {j: 0.5 * off[j] for j in range(len(names)) if not children[j]}
    for j, site in (end_sites or {}).items():
        if j not in sites or _as_float64(site).shape != (3,):
            raise UMFError(f"{path}: cannot write BVH: End Site {j} is not a leaf or not (3,)")
        sites[j] = _as_float64(site)
    hierarchy = _hierarchy_lines(dfs[0], names, children, off, sites, order, 0)
    angles = matrix_to_euler(torch.from_numpy(rot), order).numpy()  # (F, J, 3)
    motion = np.concatenate([pos, angles[:, dfs].reshape(len(rot), -1)], axis=1)
    header = f"MOTION\nFrames: {len(motion)}\nFrame Time: {frame_time:.8g}\n"
    row = " ".join([_ROW_FORMAT] * motion.shape[1]) + "\n"
    body = (row * len(motion)) % tuple(motion.ravel().tolist())  # one formatting call
    text = "HIERARCHY\n" + "\n".join(hierarchy) + "\n" + header + body
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_smpl22_bvh(
    path: str | os.PathLike,
    local_rot: ArrayLike,
    root_pos: ArrayLike,
    offsets: ArrayLike,
    fps: float = 30.0,
) -> None:
    """Write SMPL-22 motion (``umf.skeleton`` names and hierarchy, ZXY channels) as BVH.

    ``local_rot`` (T, 22, 3, 3), ``root_pos`` (T, 3) and ``offsets`` (22, 3) are what
    :func:`umf.skeleton.forward_kinematics` takes, in the caller's units (umf: metres).
    """
    if not fps > 0:
        raise UMFError(f"{path}: fps must be positive, got {fps}")
    write_bvh(path, JOINT_NAMES, PARENTS, offsets, local_rot, root_pos, 1.0 / fps, "ZXY")


def _as_float64(x: ArrayLike) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().to(torch.float64).numpy()
    return np.asarray(x, dtype=np.float64)


def _check_writer_inputs(
    path: str | os.PathLike,
    names: list[str],
    parents: list[int],
    off: np.ndarray,
    rot: np.ndarray,
    pos: np.ndarray,
    frame_time: float,
    order: str,
) -> None:
    """Reject inputs that would make an invalid or unreadable file, before touching disk."""
    J = len(names)
    problems = [
        (len(parents) != J, f"{len(parents)} parents for {J} names"),
        (len(set(names)) != J, "joint names are not unique"),
        (any(not n or len(n.split()) != 1 or n in _KEYWORDS for n in names), "bad joint name"),
        (parents.count(-1) != 1, "need exactly one root (parent -1)"),
        (any(p < -1 or p >= J for p in parents), "parent index out of range"),
        (off.shape != (J, 3), f"offsets must be ({J}, 3), got {off.shape}"),
        (
            rot.ndim != 4 or rot.shape[1:] != (J, 3, 3),
            f"local_rot must be (F, {J}, 3, 3), got {rot.shape}",
        ),
        (pos.shape != (*rot.shape[:1], 3), f"root_pos must be (F, 3), got {pos.shape}"),
        (sorted(order) != ["X", "Y", "Z"], f"order must be a permutation of XYZ, got {order!r}"),
        (not (np.isfinite(frame_time) and frame_time > 0), f"bad frame_time {frame_time}"),
        (not all(np.isfinite(a).all() for a in (off, rot, pos)), "inputs contain NaN or infinity"),
    ]
    for bad, message in problems:
        if bad:
            raise UMFError(f"{path}: cannot write BVH: {message}")


def _depth_first(children: list[list[int]], root: int) -> list[int]:
    order: list[int] = []
    stack = [root]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children[j]))
    return order


def _hierarchy_lines(
    j: int,
    names: list[str],
    children: list[list[int]],
    off: np.ndarray,
    sites: dict[int, np.ndarray],
    order: str,
    depth: int,
) -> list[str]:
    ind = "\t" * depth
    rotations = " ".join(f"{axis}rotation" for axis in order)
    channels = f"6 Xposition Yposition Zposition {rotations}" if depth == 0 else f"3 {rotations}"
    lines = [
        f"{ind}{'ROOT' if depth == 0 else 'JOINT'} {names[j]}",
        f"{ind}{{",
        f"{ind}\tOFFSET {_vector(off[j])}",
        f"{ind}\tCHANNELS {channels}",
    ]
    for c in children[j]:
        lines += _hierarchy_lines(c, names, children, off, sites, order, depth + 1)
    if not children[j]:
        lines += [
            f"{ind}\tEnd Site",
            f"{ind}\t{{",
            f"{ind}\t\tOFFSET {_vector(sites[j])}",
            f"{ind}\t}}",
        ]
    lines.append(f"{ind}}}")
    return lines


def _vector(v: np.ndarray) -> str:
    return " ".join(_ROW_FORMAT % x for x in v)
