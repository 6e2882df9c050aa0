"""Bandai-Namco-Research-Motiondataset 1 and 2 -> SMPL-22 clips with natural captions.

Data: (c) 2022 Bandai Namco Research Inc., CC BY-NC 4.0 (Kobayashi et al., "Motion
Capture Dataset for Practical Use of AI-based Motion Editing and Stylization",
arXiv:2306.08861). Anything derived from it, the umf corpus and weights included,
carries the same non-commercial licence.

Accepted inputs (any mix, found recursively under the given path): the published
``dataset-N.tar.xz`` archives, the ``data.zip`` of the dataset's git checkout, or an
extracted ``Bandai-Namco-Research-Motiondataset-N`` folder. Each clip is a BVH (30 fps,
Y up, centimetres) plus a JSON ``{"content": i, "style": j}`` whose indices name lines
of ``cfg/content_label.txt`` / ``cfg/style_label.txt``; the file name carries the same
labels, which is what we use (the cfg files are read to cross-check).
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import tarfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from umf.bvh import forward_kinematics, parse_bvh
from umf.data.clip import FPS, MotionClip
from umf.errors import UMFError

# SMPL-22 joint -> Bandai joint name; spine3 is the midpoint of Chest and Neck.
SMPL_FROM_BANDAI: tuple[str | tuple[str, str], ...] = (
    "Hips", "UpperLeg_L", "UpperLeg_R", "Spine", "LowerLeg_L", "LowerLeg_R", "Chest",
    "Foot_L", "Foot_R", ("Chest", "Neck"), "Toes_L", "Toes_R", "Neck", "Shoulder_L",
    "Shoulder_R", "Head", "UpperArm_L", "UpperArm_R", "LowerArm_L", "LowerArm_R",
    "Hand_L", "Hand_R",
)  # fmt: skip

_NAME_RE = re.compile(
    r"^dataset-(?P<set>[12])_(?P<content>[a-z-]+)_(?P<style>[a-z-]+)_(?P<take>\d+)$"
)


# --------------------------------------------------------------------- captions
# What the person does, as verb phrases (third person); several paraphrases each.
CONTENT_PHRASES: dict[str, tuple[str, ...]] = {
    "walk": ("walks forward", "walks straight ahead", "takes a walk forward"),
    "run": ("runs forward", "jogs ahead", "runs straight ahead"),
    "dash": ("dashes forward", "sprints ahead at full speed", "breaks into a sprint"),
    "walk-back": ("walks backwards", "steps backwards", "walks back while facing forward"),
    "walk-left": ("walks to the left", "moves sideways to the left", "steps to the left"),
    "walk-right": ("walks to the right", "moves sideways to the right", "steps to the right"),
    "walk-turn-left": (
        "walks and turns left",
        "walks forward, then turns to the left",
        "walks while turning left",
    ),
    "walk-turn-right": (
        "walks and turns right",
        "walks forward, then turns to the right",
        "walks while turning right",
    ),
    "bow": ("bows", "bows politely", "gives a bow"),
    "bye": ("waves goodbye", "waves a hand to say bye", "says goodbye with a wave"),
    "byebye": (
        "waves goodbye with both hands",
        "waves both hands to say bye-bye",
        "says bye-bye, waving widely",
    ),
    "guide": (
        "gestures to show the way",
        "guides someone with a hand gesture",
        "points the way with an open hand",
    ),
    "respond": (
        "responds to a call",
        "answers someone who calls, raising a hand",
        "reacts to being called",
    ),
    "call": ("calls out to someone", "calls someone over", "beckons someone to come"),
    "punch": ("throws punches", "punches", "throws a punch forward"),
    "kick": ("kicks", "kicks forward", "throws a kick"),
    "slash": ("slashes with a sword", "swings a sword", "makes a slashing attack"),
    "dance-long": ("dances", "performs a long dance", "dances energetically"),
    "dance-short": ("dances", "performs a short dance", "does a quick dance"),
    "wave-both-hands": (
        "waves both hands",
        "waves with both hands above the head",
        "waves both arms",
    ),
    "wave-left-hand": (
        "waves the left hand",
        "waves with the left hand",
        "raises the left hand and waves",
    ),
    "wave-right-hand": (
        "waves the right hand",
        "waves with the right hand",
        "raises the right hand and waves",
    ),
    "raise-up-both-hands": ("raises both hands", "puts both hands up", "lifts both arms up high"),
    "raise-up-left-hand": ("raises the left hand", "puts the left hand up", "lifts the left arm"),
    "raise-up-right-hand": (
        "raises the right hand",
        "puts the right hand up",
        "lifts the right arm",
    ),
}

# How they do it: (adverbial phrase, adjective for the subject). None = neutral.
STYLE_PHRASES: dict[str, tuple[tuple[str, ...], tuple[str, ...]] | None] = {
    "normal": None,
    "happy": (("happily", "cheerfully"), ("happy", "cheerful")),
    "sad": (("sadly", "gloomily"), ("sad", "downcast")),
    "angry": (("angrily", "furiously"), ("angry", "furious")),
    "proud": (("proudly", "with pride"), ("proud", "confident")),
    "not-confident": (("timidly", "hesitantly"), ("shy", "insecure")),
    "masculinity": (("in a masculine way", "in a manly manner"), ("masculine",)),
    "masculine": (("in a masculine way", "in a manly manner"), ("masculine",)),
    "feminine": (("in a feminine way", "gracefully"), ("feminine",)),
    "childish": (("like a child", "in a childish way"), ("childish", "playful")),
    "old": (("like an old person", "slowly, like an elderly person"), ("old", "elderly")),
    "elderly": (("like an elderly person", "slowly, like an old person"), ("elderly", "old")),
    "tired": (("wearily", "as if tired"), ("tired", "weary")),
    "exhausted": (("looking exhausted", "wearily"), ("exhausted", "worn-out")),
    "active": (("energetically", "actively"), ("energetic", "lively")),
    "youthful": (("youthfully", "with youthful energy"), ("youthful", "young")),
    "musical": (("rhythmically, like in a musical", "theatrically"), ("theatrical",)),
    "giant": (("heavily, like a giant", "with big heavy movements"), ("giant", "hulking")),
    "chimpira": (("with a swagger, like a thug", "like a street punk"), ("swaggering",)),
}

_SUBJECTS = ("a person", "someone", "the person", "somebody")  # gender is not labelled


def captions_for(content: str, style: str, n: int = 4, seed: str = "") -> list[str]:
    """Several distinct natural captions for a labelled clip, deterministic per seed."""
    if content not in CONTENT_PHRASES:
        raise UMFError(f"unknown Bandai content label {content!r}")
    if style not in STYLE_PHRASES:
        raise UMFError(f"unknown Bandai style label {style!r}")
    rng = np.random.default_rng(
        int(hashlib.sha1(f"{seed}|{content}|{style}".encode()).hexdigest()[:8], 16)
    )
    verbs = CONTENT_PHRASES[content]
    style_words = STYLE_PHRASES[style]
    candidates: list[str] = []
    for verb in verbs:
        for subject in _SUBJECTS:
            if style_words is None:
                candidates.append(f"{subject} {verb}.")
                continue
            adverbs, adjectives = style_words
            for adv in adverbs:
                candidates.append(f"{subject} {verb} {adv}.")
            for adj in adjectives:
                if subject in ("a person", "someone", "somebody"):
                    article = "an" if adj[0] in "aeiou" else "a"
                    candidates.append(f"{article} {adj} person {verb}.")
    candidates = sorted(set(candidates))
    picks = rng.permutation(len(candidates))[: min(n, len(candidates))]
    return [candidates[i][0].upper() + candidates[i][1:] for i in picks]


# --------------------------------------------------------------------- file access
@dataclass(frozen=True)
class BandaiFile:
    """One clip's files, wherever they live (folder, tar.xz or zip)."""

    name: str  # e.g. dataset-1_bow_normal_001
    bvh: bytes
    label: dict | None
    origin: str  # where it came from, for messages


def _parse_name(name: str) -> dict[str, str]:
    m = _NAME_RE.match(name)
    if not m:
        raise UMFError(f"not a Bandai clip name: {name!r}")
    return m.groupdict()


def _iter_members(path: Path) -> Iterator[tuple[str, bytes]]:
    """(member name, bytes) of .bvh/.json/.txt files in an archive or a folder tree."""
    suffixes = (".bvh", ".json", ".txt", ".zip")
    if path.is_dir():
        for p in sorted(path.rglob("*")):
            if p.is_file() and p.suffix in suffixes:
                yield str(p), p.read_bytes()
            elif p.is_file() and p.name.endswith(".tar.xz"):
                yield from _iter_members(p)
        return
    if path.name.endswith((".tar.xz", ".tar.gz", ".tar", ".tgz")):
        try:
            with tarfile.open(path, "r:*") as tar:
                for member in tar:
                    if member.isfile() and member.name.endswith(suffixes):
                        fh = tar.extractfile(member)
                        if fh is not None:
                            yield f"{path}:{member.name}", fh.read()
        except (tarfile.TarError, EOFError, OSError) as exc:
            raise UMFError(f"{path}: unreadable archive ({exc})") from exc
        return
    if path.suffix == ".zip":
        try:
            with zipfile.ZipFile(path) as zf:
                for info in zf.infolist():
                    if not info.is_dir() and info.filename.endswith(suffixes):
                        yield f"{path}:{info.filename}", zf.read(info)
        except (zipfile.BadZipFile, OSError) as exc:
            raise UMFError(f"{path}: unreadable archive ({exc})") from exc
        return
    raise UMFError(f"{path}: expected a Bandai folder, .tar.xz or .zip")


def iter_bandai_files(path: str | Path) -> Iterator[BandaiFile]:
    """All clips under ``path``, in sorted name order, each with its JSON label."""
    path = Path(path)
    if not path.exists():
        raise UMFError(f"Bandai data not found: {path}")
    bvhs: dict[str, tuple[str, bytes]] = {}
    labels: dict[str, dict | None] = {}

    def collect(members: Iterator[tuple[str, bytes]]) -> None:
        for origin, data in members:
            base = origin.rsplit("/", 1)[-1].rsplit(":", 1)[-1]
            stem, _, ext = base.rpartition(".")
            if ext == "zip":
                zpath = Path(origin)
                if zpath.exists():
                    collect(_iter_members(zpath))
                else:  # a zip inside an archive
                    try:
                        with zipfile.ZipFile(io.BytesIO(data)) as zf:
                            collect(
                                (f"{origin}:{i.filename}", zf.read(i))
                                for i in zf.infolist()
                                if i.filename.endswith((".bvh", ".json"))
                            )
                    except (zipfile.BadZipFile, EOFError, OSError) as exc:
                        raise UMFError(f"{origin}: unreadable zip inside the archive "
                                       f"({type(exc).__name__})") from None  # fmt: skip
            elif ext == "bvh" and _NAME_RE.match(stem):
                bvhs[stem] = (origin, data)
            elif ext == "json" and _NAME_RE.match(stem):
                try:
                    label = json.loads(data.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError):
                    label = None
                # a label must be an object ({"content": i, "style": j}); `5` or a list is none
                labels[stem] = label if isinstance(label, dict) else None

    collect(_iter_members(path))
    for name in sorted(bvhs):
        origin, data = bvhs[name]
        yield BandaiFile(name=name, bvh=data, label=labels.get(name), origin=origin)


# --------------------------------------------------------------------- retargeting
def retarget_to_smpl22(positions_cm: np.ndarray, names: list[str]) -> np.ndarray:
    """Bandai FK positions (F, J, 3) in cm -> SMPL-22 joints (F, 22, 3) in metres."""
    index = {n: i for i, n in enumerate(names)}
    cols = []
    for src in SMPL_FROM_BANDAI:
        if isinstance(src, tuple):
            cols.append(0.5 * (positions_cm[:, index[src[0]]] + positions_cm[:, index[src[1]]]))
        else:
            cols.append(positions_cm[:, index[src]])
    return (np.stack(cols, axis=1) / 100.0).astype(np.float32)


def resampled_length(frames: int, fps_in: float, fps_out: float = FPS) -> int:
    """How many frames :func:`resample` makes of ``frames`` at ``fps_in``: every output
    time within the input's duration."""
    if abs(fps_in - fps_out) < 1e-3:
        return frames
    return int(np.floor((frames - 1) / fps_in * fps_out + 1e-6)) + 1


def resample(
    joints: np.ndarray,
    fps_in: float,
    fps_out: float = FPS,
    first: int = 0,
    count: int | None = None,
) -> np.ndarray:
    """Linear resampling of (P, T, 22, 3) joints over time; identity when rates agree.

    ``first`` and ``count`` (output frames) return only that window of the result, the same
    values as cutting it afterwards, but reading only the input frames it needs: a long file
    costs what its window costs."""
    t_in = joints.shape[1]
    same = abs(fps_in - fps_out) < 1e-3
    t_out = resampled_length(t_in, fps_in, fps_out)
    if first == 0 and count is None and same:
        return joints
    first = min(max(first, 0), t_out)
    count = t_out - first if count is None else max(0, min(count, t_out - first))
    if same or count == 0:
        return joints[:, first : first + count]
    src = (torch.arange(count, dtype=torch.float64) + first) * (fps_in / fps_out)
    lo = src.floor().long().clamp(max=t_in - 1)
    hi = (lo + 1).clamp(max=t_in - 1)
    start, stop = int(lo[0]), int(hi[-1]) + 1
    part = np.ascontiguousarray(joints[:, start:stop])
    x = torch.from_numpy(part).permute(0, 2, 3, 1).reshape(1, -1, stop - start)
    w = (src - lo).to(x.dtype)
    out = x[..., lo - start] * (1 - w) + x[..., hi - start] * w
    p = joints.shape[0]
    return out.reshape(p, 22, 3, count).permute(0, 3, 1, 2).contiguous().numpy()


def load_clip(f: BandaiFile, n_captions: int = 4) -> MotionClip:
    """Read, check and retarget one clip."""
    labels = _parse_name(f.name)
    if f.label is not None and not {"content", "style"} <= set(f.label):
        raise UMFError(f"{f.origin}: JSON label lacks content/style")
    bvh = parse_bvh(f.bvh.decode("utf-8", errors="replace"), f.origin)
    missing = {n for s in SMPL_FROM_BANDAI for n in ((s,) if isinstance(s, str) else s)} - set(
        bvh.names
    )
    if missing:
        raise UMFError(f"{f.origin}: BVH lacks joints {sorted(missing)}")
    positions, _ = forward_kinematics(bvh)
    positions = np.asarray(positions, dtype=np.float64)
    if not np.isfinite(positions).all():
        raise UMFError(f"{f.origin}: non-finite values in the motion")
    joints = retarget_to_smpl22(positions, bvh.names)[None]
    joints = resample(joints, 1.0 / bvh.frame_time)
    return MotionClip(
        id=f.name,
        source="bandai",
        joints=joints,
        captions=captions_for(labels["content"], labels["style"], n_captions, seed=f.name),
        fps=FPS,
        meta={
            "dataset": int(labels["set"]),
            "content": labels["content"],
            "style": labels["style"],
            "take": int(labels["take"]),
            "file": f.origin,
            "source_fps": round(1.0 / bvh.frame_time, 3),
        },
    )


def load_bandai(
    path: str | Path, problems: list[tuple[str, str]] | None = None
) -> Iterator[MotionClip]:
    """Every readable clip under ``path``; unreadable ones are reported in ``problems``.

    A clip that fails to load is never dropped silently: its origin and the reason go
    into ``problems`` (or, without that list, the error is raised).
    """
    for f in iter_bandai_files(path):
        try:
            yield load_clip(f)
        except (UMFError, ValueError, KeyError, IndexError) as exc:
            if problems is None:
                raise
            problems.append(
                (f.origin, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            )
