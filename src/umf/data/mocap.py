"""Any mocap library as training data: a folder of BVH / DeepMimic files -> clips.

``umf data prepare --mocap DIR`` (repeatable). What DIR may hold:

- motion files, found recursively: ``*.bvh`` on any skeleton of :mod:`umf.data.skeletons`
  (or one described by ``DIR/skeleton.json``), and DeepMimic ``*.txt`` / ``*.json`` files
  with a ``"Frames"`` list (:mod:`umf.data.deepmimic`); any unit (the one that makes the
  body an adult's size, else a stature scale) and frame rate (resampled to 30 fps);
- ``captions.csv`` (header ``file,caption`` and optionally ``label``): one row per caption,
  several rows per file, ``file`` relative to DIR (or a take's name); ``label`` names the
  action (it groups clips for the split); a file without a caption is captioned from its
  name, and the report lists it;
- ``takes.csv`` (header ``take,file,person``, optionally ``dx,dz`` and ``caption``): files
  captured together. Each take is one real multi-person clip in its shared world frame (its
  files must have the same frame rate and length, and one unit is used for all of them);
  ``dx,dz`` (metres) shift that person on the floor, a placement correction for captures
  whose files do not quite share a frame (say so in the library's README); ``caption`` is
  what that person does in the take, their own caption for the per-person prompts ("A
  person leads their partner in a salsa dance."; ``meta["person_captions"]``).

Every clip keeps its file, the skeleton it was read as, the unit and frame rate used. Takes
and files are split by :func:`umf.data.corpus.assign_splits` (one take is one clip, so no take
is in two splits). A file that cannot be read is skipped with its reason in the report; a
malformed ``captions.csv`` / ``takes.csv`` or a take whose files disagree is an error.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from umf.data.clip import FPS, MotionClip
from umf.data.skeletons import SkeletonMap, read_skeleton_json, recognise
from umf.errors import UMFError
from umf.units import choose_unit

MOTION_SUFFIXES = (".bvh", ".txt", ".json")
META_FILES = {"captions.csv", "takes.csv", "skeleton.json"}
MAX_SHIFT = 100.0  # m: takes.csv's dx/dz correct a placement; 1e30 made a corpus of infinities
MAX_TAKE_LENGTH_MISMATCH = 1  # frames: conversions sometimes drop the last frame of one file
REFERENCE_JUMP = 0.06  # of the body's size: a first frame this far from the next is a pose
LOOP_SECONDS = 6.0  # a looping clip (DeepMimic "Loop": "wrap") is repeated up to this long


class TakeMismatch(UMFError):
    """The files of one take disagree (frame rate, length, unit): the library is wrong, so
    ``prepare`` stops instead of skipping the take."""


@dataclass
class RawMotion:
    """One file's people in file units, before the unit is chosen (a take shares one)."""

    joints: np.ndarray  # (F, 22, 3), file units
    fps: float
    skeleton: str
    unit: float | None = None  # fixed by the format or skeleton.json
    loops: bool = False


@dataclass
class MocapLibrary:
    """The files, captions and takes of one ``--mocap`` folder."""

    root: Path
    files: list[str]  # relative paths, sorted
    captions: dict[str, list[str]] = field(default_factory=dict)
    labels: dict[str, str] = field(default_factory=dict)
    takes: dict[str, list[tuple[str, int, float, float]]] = field(default_factory=dict)
    # take -> person (1-based) -> that person's own captions (takes.csv's caption column)
    person_captions: dict[str, dict[int, list[str]]] = field(default_factory=dict)
    skeleton: SkeletonMap | None = None


# --------------------------------------------------------------------- reading files
def read_motion(path: Path, skeleton: SkeletonMap | None = None) -> RawMotion:
    """SMPL-22 joints of one motion file, in its own unit (one-line errors)."""
    if not path.is_file():
        raise UMFError(f"motion file not found: {path}")
    try:
        text = path.read_bytes().decode("utf-8-sig", errors="replace")
    except OSError as exc:
        raise UMFError(f"{path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    if path.suffix.lower() == ".bvh":
        raw = _read_bvh(text, path, skeleton)
    else:
        from umf.data.deepmimic import is_deepmimic, read_deepmimic

        if not is_deepmimic(text):
            raise UMFError(f"{path}: not a DeepMimic motion (no 'Frames')")
        joints, fps, loops = read_deepmimic(path, text)
        raw = RawMotion(joints, fps, "deepmimic", 1.0, loops)
    if skeleton is not None and skeleton.fps is not None:
        raw.fps = skeleton.fps
    if skeleton is not None and skeleton.unit is not None:
        raw.unit = skeleton.unit
    if not np.isfinite(raw.joints).all():
        raise UMFError(f"{path}: non-finite values in the motion")
    if not 1.0 <= raw.fps <= 1000.0:
        raise UMFError(f"{path}: implausible frame rate {raw.fps:g} fps")
    if raw.joints.shape[0] < 2:
        raise UMFError(f"{path}: fewer than 2 frames")
    check_bones(raw.joints, str(path))
    return raw


def check_bones(joints: np.ndarray, label: str) -> None:
    """A mapping that puts two connected SMPL joints at one point (a bone of no length) gives
    a body no rigid skeleton or rotation can describe: one line naming the two joints."""
    from umf.skeleton import JOINT_NAMES, PARENTS
    from umf.units import body_span

    span = body_span(joints)
    for k, p in enumerate(PARENTS):
        if (
            p >= 0
            and np.median(np.linalg.norm(joints[:, k] - joints[:, p], axis=-1)) < 0.005 * span
        ):
            raise UMFError(f"{label}: the mapping puts {JOINT_NAMES[k]} and {JOINT_NAMES[p]} at "
                           "one point; map them to different joints (skeleton.json)")  # fmt: skip


def _read_bvh(text: str, path: Path, skeleton: SkeletonMap | None) -> RawMotion:
    from umf.bvh import forward_kinematics, parse_bvh

    bvh = parse_bvh(text, str(path))
    if not bvh.frame_time > 0:
        raise UMFError(f"{path}: 'Frame Time: {bvh.frame_time:g}' (must be positive seconds)")
    table = (
        skeleton if skeleton is not None and skeleton.sources else recognise(bvh.names, str(path))
    )
    missing = table.missing(bvh.names)
    if missing:
        raise UMFError(f"{path}: no joint(s) {', '.join(missing)} for the {table.name} mapping")
    pos, rot = forward_kinematics(bvh)
    joints = table.apply(bvh.names, pos, rot, bvh.end_sites)
    return RawMotion(drop_reference_pose(joints), 1.0 / bvh.frame_time, table.name)


def drop_reference_pose(joints: np.ndarray) -> np.ndarray:
    """Without a first frame that is a reference pose rather than motion: conversions such
    as CMU's cgspeed BVH start with a T-pose. Told by the pose (root-relative joints) jumping
    by more than :data:`REFERENCE_JUMP` on average between frames 0 and 1, which no captured
    motion does in one frame."""
    if joints.shape[0] < 3:
        return joints
    rel = joints[:3] - joints[:3, :1]
    first, second = (np.linalg.norm(rel[1] - rel[0], axis=-1).mean(),
                     np.linalg.norm(rel[2] - rel[1], axis=-1).mean())  # fmt: skip
    scale = np.ptp(rel[1], axis=0).max()  # the body's size in file units
    if first > REFERENCE_JUMP * scale and first > 10 * second:
        return joints[1:]
    return joints


def to_metres(raws: list[RawMotion]) -> tuple[list[np.ndarray], float, str]:
    """The people of one take in metres with one shared unit (the file's or skeleton.json's
    when fixed, else chosen on all of them together)."""
    fixed = {r.unit for r in raws if r.unit is not None}
    if len(fixed) > 1:
        raise TakeMismatch("the files of one take have different units")
    if fixed:
        unit, how = fixed.pop(), "given"
    else:
        unit, how = choose_unit(np.concatenate([r.joints for r in raws]))
    with np.errstate(over="ignore"):  # 1e300 in a file: inf here, refused by the caller's check
        return [(r.joints * unit).astype(np.float32) for r in raws], unit, how


def tile_loop(joints: np.ndarray, min_frames: int) -> np.ndarray:
    """A cyclic clip (T, 22, 3) repeated until it has ``min_frames`` frames: each repeat
    starts where (and facing where) the previous one ended, so a walk keeps walking and a
    spin keeps turning. The clip's last frame is the next cycle's first, as in DeepMimic."""
    from umf.data.relations import facing_dirs

    out = [joints]
    cycle = joints[1:]
    f0 = facing_dirs(joints[0])
    a0 = np.arctan2(f0[0], f0[1])
    while sum(len(c) for c in out) < min_frames and len(joints) > 1:
        end = out[-1][-1]
        f1 = facing_dirs(end)
        yaw = np.arctan2(f1[0], f1[1]) - a0  # about +Y, x-z plane
        c, s = np.cos(yaw), np.sin(yaw)
        rel = cycle - joints[0, 0] * np.array([1.0, 0.0, 1.0])
        x, z = rel[..., 0], rel[..., 2]
        nxt = rel.copy()
        nxt[..., 0], nxt[..., 2] = c * x + s * z, -s * x + c * z
        nxt[..., [0, 2]] += end[0, [0, 2]]
        out.append(nxt.astype(joints.dtype))
    return np.concatenate(out)


# --------------------------------------------------------------------- the folder
def _read_csv(path: Path, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> list[dict]:
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise UMFError(f"{path}: not a readable UTF-8 file ({type(exc).__name__})") from None
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    if tuple(header[: len(required)]) != required or not set(header) <= set(required + optional):
        raise UMFError(f"{path}: header must be {','.join(required)}"
                       + (f" (optionally {','.join(optional)})" if optional else "")
                       + f", got {','.join(header) or 'nothing'}")  # fmt: skip
    out, n = [], reader.line_num + 1
    for raw in reader:
        if None in raw:  # more fields than the header names: a stray comma, a lost column
            raise UMFError(f"{path}, line {n}: {len(header) + len(raw[None])} fields, the "
                           f"header names {len(header)}")  # fmt: skip
        if any("\n" in v or "\r" in v for v in raw.values() if v):
            raise UMFError(f"{path}, line {n}: a field runs over several lines (a quote left "
                           f"open?)")  # fmt: skip
        row = {k.strip(): (v or "").strip() for k, v in raw.items()}
        if any(not row.get(k) for k in required):
            raise UMFError(
                f"{path}, line {n}: empty {'/'.join(k for k in required if not row.get(k))}"
            )
        row["_line"] = n
        out.append(row)
        n = reader.line_num + 1
    return out


def scan_library(root: str | Path) -> MocapLibrary:
    """Files, captions, takes and skeleton mapping of a mocap folder (nothing read yet)."""
    root = Path(root)
    if not root.is_dir():
        raise UMFError(f"mocap library not found (not a folder): {root}")
    files = sorted(
        p.relative_to(root).as_posix()
        for p in root.rglob("*")
        if p.is_file() and p.suffix.lower() in MOTION_SUFFIXES and p.name not in META_FILES
        and not any(part.startswith(".") for part in p.relative_to(root).parts)
    )  # fmt: skip
    lib = MocapLibrary(root, files)
    if (root / "skeleton.json").exists():
        lib.skeleton = read_skeleton_json(root / "skeleton.json")
    if (root / "takes.csv").exists():
        path = root / "takes.csv"
        for row in _read_csv(path, ("take", "file", "person"), ("dx", "dz", "caption")):
            where = f"{path}, line {row['_line']}"
            if row["file"] not in files:
                raise UMFError(f"{where}: no motion file {row['file']!r} in {root}")
            try:
                person = int(row["person"])
                dx, dz = float(row.get("dx") or 0), float(row.get("dz") or 0)
            except ValueError:
                raise UMFError(f"{where}: person must be a whole number, dx/dz numbers") from None
            if not 1 <= person <= 16 or not (abs(dx) <= MAX_SHIFT and abs(dz) <= MAX_SHIFT):
                raise UMFError(f"{where}: person must be 1..16 and dx/dz metres within "
                               f"±{MAX_SHIFT:g}")  # fmt: skip
            lib.takes.setdefault(row["take"], []).append((row["file"], person, dx, dz))
            if row.get("caption"):
                own = lib.person_captions.setdefault(row["take"], {})
                own.setdefault(person, []).append(row["caption"])
        for take, members in lib.takes.items():
            people = sorted(p for _, p, *_ in members)
            if people != list(range(1, len(people) + 1)):
                raise UMFError(f"{path}: take {take!r} must number its people 1..{len(people)}, "
                               f"got {people}")  # fmt: skip
            members.sort(key=lambda m: m[1])
        taken = [f for ms in lib.takes.values() for f, *_ in ms]
        twice = sorted({f for f in taken if taken.count(f) > 1})
        if twice:
            raise UMFError(f"{path}: file(s) in more than one take: {', '.join(twice)}")
    if (root / "captions.csv").exists():
        path = root / "captions.csv"
        known = set(files) | set(lib.takes)
        for row in _read_csv(path, ("file", "caption"), ("label",)):
            key = row["file"]
            if key not in known:
                raise UMFError(f"{path}, line {row['_line']}: no motion file or take {key!r}")
            lib.captions.setdefault(key, []).append(row["caption"])
            if row.get("label"):
                lib.labels[key] = row["label"]
    return lib


def name_caption(name: str) -> str:
    """A caption from a file name: ``jump_up-02.bvh`` -> "a person: jump up"."""
    words = re.sub(r"[\d_\-.]+", " ", Path(name).stem).split()
    return "a person: " + " ".join(words) if words else "a person moves"


def _label(name: str) -> str:
    return re.sub(r"[\d_\-. ]+", "-", Path(name).stem).strip("-").lower() or "motion"


def load_mocap(
    path: str | Path, problems: list[tuple[str, str]] | None = None, source: str = "mocap"
) -> Iterator[MotionClip]:
    """Every readable take and single file of a mocap folder as a clip (module notes).

    Unreadable files go into ``problems`` with their reason; files captioned from their
    name go there too (reason "no caption in captions.csv: captioned ..."), so the report
    lists them. Without ``problems`` the first error is raised.
    """
    lib = scan_library(path)
    if not lib.files:
        raise UMFError(f"{lib.root}: no motion files (.bvh, or DeepMimic .txt/.json)")
    in_take = {f: take for take, ms in lib.takes.items() for f, *_ in ms}
    items: list[tuple[str, list[tuple[str, int, float, float]]]] = [
        (take, ms) for take, ms in sorted(lib.takes.items())
    ]
    items += [(f, [(f, 1, 0.0, 0.0)]) for f in lib.files if f not in in_take]
    for key, members in items:
        is_take = key in lib.takes
        try:
            raws = []
            for f, *_ in members:
                try:
                    raws.append(read_motion(lib.root / f, lib.skeleton))
                except UMFError as exc:
                    if is_take:  # a take without one of its people is not that take
                        raise UMFError(f"take {key!r}: {exc}") from None
                    raise
            clip = _clip(lib, key, members, raws, is_take, source)
        except UMFError as exc:
            if problems is None or isinstance(exc, TakeMismatch):
                raise
            where, reason = str(lib.root / key), str(exc).splitlines()[0]
            problems.append((where, reason.removeprefix(f"{where}: ")))
            continue
        if key not in lib.captions and problems is not None:
            problems.append((str(lib.root / key), f"no caption in captions.csv: captioned "
                                                  f"{clip.captions[0]!r}"))  # fmt: skip
        yield clip


def _clip(lib: MocapLibrary, key: str, members, raws: list[RawMotion], is_take: bool,
          source: str) -> MotionClip:  # fmt: skip
    from umf.data.bandai import resample

    rates = {round(r.fps, 3) for r in raws}
    if len(rates) > 1:
        raise TakeMismatch(f"take {key!r}: its files have different frame rates "
                       f"({', '.join(f'{r:g}' for r in sorted(rates))} fps)")  # fmt: skip
    lengths = [r.joints.shape[0] for r in raws]
    if max(lengths) - min(lengths) > MAX_TAKE_LENGTH_MISMATCH:
        raise TakeMismatch(f"take {key!r}: its files have different lengths "
                       f"({', '.join(map(str, lengths))} frames)")  # fmt: skip
    people, unit, how = to_metres(raws)
    t = min(lengths)
    joints = np.stack([p[:t] for p in people])
    for i, (_, _, dx, dz) in enumerate(members):
        joints[i, :, :, 0] += dx
        joints[i, :, :, 2] += dz
    joints = resample(np.ascontiguousarray(joints), raws[0].fps, FPS)
    captions = lib.captions.get(key) or [name_caption(key)]
    meta = {
        "content": lib.labels.get(key) or _label(key),
        "style": "",
        "file": key if not is_take else ",".join(f for f, *_ in members),
        "library": lib.root.name,
        "skeleton": ",".join(sorted({r.skeleton for r in raws})),
        "unit": round(unit, 6),
        "unit_from": how,
        "source_fps": round(raws[0].fps, 3),
    }
    if is_take:
        meta["take"] = key
        own = lib.person_captions.get(key, {})
        if own:
            meta["person_captions"] = [own.get(p, []) for _, p, *_ in members]
        from umf.data.relations import measured_relation

        meta["measured"] = measured_relation(joints)
    if raws[0].loops and len(raws) == 1:
        meta["loops"] = True
        meta["cycle_frames"] = joints.shape[1]
        joints = tile_loop(joints[0], int(LOOP_SECONDS * FPS))[None]
    cid = f"{lib.root.name}/{Path(key).with_suffix('').as_posix() if not is_take else key}"
    return MotionClip(cid, source, joints, captions, FPS, meta=meta)
