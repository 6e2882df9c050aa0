"""The versioned training corpus: real clips, their split, composed scenes, normaliser.

Layout of a corpus directory (``umf data prepare --out DIR``)::

    manifest.json          format version, sources, per-split counts, seed, licence
    clips.json             one entry per clip: id, source, split, captions, P, T, labels
    clips.npz              joints of all clips, concatenated (sum P*T, 22, 3) float32
    scenes.json            composed scene recipes per split (see umf.data.scenes)
    normalizer.safetensors per-dimension mean/std of the 262-d features (train split)
    cache/<source>-<fingerprint>.npz   per-source conversion cache (reused by re-runs)

Scenes are stored as recipes and rebuilt exactly from the clips, so the corpus stays
small. Everything derived from Bandai data is CC BY-NC 4.0.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import time
import warnings
import zipfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from umf.data.clip import FPS, MotionClip
from umf.data.composer import compose_corpus
from umf.data.humanml3d import SkippedItemWarning
from umf.data.scenes import Actor, build_scene, build_scene_features
from umf.errors import UMFError
from umf.io import atomic_path, remove_stale_temporaries, write_json_atomic
from umf.representation import (
    Normalizer,
    assemble_features,
    canonicalize_scene,
    joints_to_rot6d,
)
from umf.rotations import matrix_to_6d
from umf.version import __version__

FORMAT = "umf-corpus"
FORMAT_VERSION = 1
CACHE_VERSION = 4  # bump when the per-source conversion changes
SPLITS = ("train", "val", "test")
BANDAI_ATTRIBUTION = (
    "Bandai-Namco-Research-Motiondataset, (c) 2022 Bandai Namco Research Inc., CC BY-NC 4.0; "
    "Kobayashi et al., arXiv:2306.08861, 2023"
)


@dataclass
class PrepareConfig:
    """Settings of ``umf data prepare`` (also the defaults of the Python API)."""

    seed: int = 1234
    val_fraction: float = 0.1
    test_fraction: float = 0.1
    train_scenes: int = 3000
    val_scenes: int = 200
    test_scenes: int = 300
    test_groups: int = 200
    group_sizes: tuple[int, ...] = (3, 4, 5, 6)
    normalizer_max_frames: int = 200_000


# --------------------------------------------------------------------- splits
def _hash01(text: str) -> float:
    return int(hashlib.sha1(text.encode()).hexdigest()[:12], 16) / float(16**12)


def assign_splits(
    clips: list[dict[str, Any]], val_fraction: float, test_fraction: float
) -> dict[str, str]:
    """Split by source clip, stratified by (source, dataset, content), deterministic.

    Clips whose dataset defines a split keep it. Within each stratum clips are ordered
    by a hash of their id; a stratum of 2 or more gives at least one test clip and one of
    3 or more also a val clip, so (nearly) every action appears in held-out scenes.
    """
    out: dict[str, str] = {}
    strata: dict[tuple, list[str]] = {}
    for c in clips:
        if c.get("split") in SPLITS:
            out[c["id"]] = c["split"]
            continue
        key = (c["source"], c.get("dataset"), c.get("content"))
        strata.setdefault(key, []).append(c["id"])
    for ids in strata.values():
        ids = sorted(ids, key=_hash01)
        n = len(ids)
        # rare actions (2 takes) still get one held-out take, so test scenes cover them
        n_test = max(1, round(test_fraction * n)) if n >= 2 else 0
        n_val = max(1, round(val_fraction * n)) if n >= 3 else 0
        for i, cid in enumerate(ids):
            out[cid] = "test" if i < n_test else "val" if i < n_test + n_val else "train"
    return out


# --------------------------------------------------------------------- source cache
def _fingerprint(path: Path) -> str:
    """Cheap identity of an input (names, sizes, mtimes) to decide cache reuse."""
    h = hashlib.sha1(f"{FORMAT_VERSION}.{CACHE_VERSION}|{path.resolve()}".encode())
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for p in files:
        st = p.stat()
        h.update(f"{p.relative_to(path.parent)}|{st.st_size}|{int(st.st_mtime)}".encode())
    return h.hexdigest()[:16]


def _save_clips(
    path: Path, clips: list[MotionClip], skipped: list[tuple[str, str]] | None = None
) -> None:
    index = [
        {
            "id": c.id, "source": c.source, "split": c.split, "captions": c.captions,
            "num_people": c.num_people, "num_frames": c.num_frames, **c.meta,
        }
        for c in clips
    ]  # fmt: skip
    joints = _concat([c.joints.reshape(-1, 22, 3) for c in clips], (22, 3))
    arrays = {"joints": joints, "index": np.array(json.dumps(index))}
    if skipped is not None:  # the cache remembers the inputs it could not read
        arrays["skipped"] = np.array(json.dumps([list(p) for p in skipped]))
    if clips and all(c.rot6d is not None for c in clips):
        arrays["rot6d"] = _concat([c.rot6d.reshape(-1, 21, 6) for c in clips], (21, 6))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _concat(arrays: list[np.ndarray], tail: tuple[int, ...]) -> np.ndarray:
    if not arrays:
        return np.zeros((0, *tail), np.float32)
    return np.concatenate(arrays).astype(np.float32)


def _load_clips(path: Path) -> list[MotionClip]:
    with np.load(path) as z:
        joints = z["joints"]
        rot6d = z["rot6d"] if "rot6d" in z else None
        index = json.loads(str(z["index"]))
    out, pos = [], 0
    for e in index:
        p, t = e["num_people"], e["num_frames"]
        j = joints[pos : pos + p * t].reshape(p, t, 22, 3)
        r = None if rot6d is None else rot6d[pos : pos + p * t].reshape(p, t, 21, 6)
        pos += p * t
        meta = {
            k: v
            for k, v in e.items()
            if k not in {"id", "source", "split", "captions", "num_people", "num_frames"}
        }
        out.append(
            MotionClip(e["id"], e["source"], j, e["captions"], FPS, None, r, e["split"], meta)
        )
    return out


def load_source(
    name: str,
    path: Path,
    loader: Callable[[Path, list[tuple[str, str]]], Iterable[MotionClip]],
    cache_dir: Path,
    problems: list[tuple[str, str]],
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> tuple[list[MotionClip], bool]:
    """Clips of one source, converted once and cached; returns (clips, reused_cache)."""
    cache = cache_dir / f"{name}-{_fingerprint(path)}.npz"
    if cache.exists():
        try:
            clips = _load_clips(cache)
            skipped = _load_skipped(cache)
            problems.extend(skipped)
            return clips, True
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            cache.unlink(missing_ok=True)  # a broken cache is rebuilt, never trusted
            log(f"{cache}: conversion cache unreadable (truncated?); converting {name} again")
    clips: list[MotionClip] = []
    found: list[tuple[Any, str]] = []
    with warnings.catch_warnings():  # skipped items are reported once, by the caller
        warnings.simplefilter("ignore", SkippedItemWarning)
        for clip in tqdm(
            loader(path, found), desc=f"reading {name}", unit="clip", disable=not progress
        ):
            clip.rot6d = clip_rot6d(clip)
            clip.rotations = None  # kept as rot6d from here on
            clips.append(clip)
    problems.extend((str(origin), str(reason)) for origin, reason in found)
    for stale in cache_dir.glob(f"{name}-*.npz"):  # older inputs or conversion versions
        stale.unlink(missing_ok=True)
    _save_clips(cache, clips, [(str(o), str(r)) for o, r in found])
    return clips, False


def _load_skipped(path: Path) -> list[tuple[str, str]]:
    """The inputs a cached conversion skipped (a cache without the record is rebuilt)."""
    with np.load(path) as z:
        if "skipped" not in z:
            raise KeyError("skipped")
        return [(str(o), str(r)) for o, r in json.loads(str(z["skipped"]))]


def clip_rot6d(clip: MotionClip) -> np.ndarray:
    """Local 6-D rotations (P, T, 21, 6): the source's own when given, else by IK."""
    if clip.rotations is not None:
        rot = torch.from_numpy(np.ascontiguousarray(clip.rotations[:, :, 1:]))
        return matrix_to_6d(rot).numpy().astype(np.float32)
    return np.stack([joints_to_rot6d(torch.from_numpy(p)).numpy() for p in clip.joints]).astype(
        np.float32
    )


def _bandai_loader(path: Path, problems: list[tuple[str, str]]) -> Iterator[MotionClip]:
    from umf.data.bandai import load_bandai

    return load_bandai(path, problems)


def _humanml3d_loader(path: Path, problems: list[tuple[str, str]]) -> Iterator[MotionClip]:
    from umf.data.humanml3d import load_humanml3d

    return load_humanml3d(path, problems=problems)


def _interhuman_loader(path: Path, problems: list[tuple[str, str]]) -> Iterator[MotionClip]:
    from umf.data.interhuman import load_interhuman

    return load_interhuman(path, problems=problems)


def _mocap_loader(path: Path, problems: list[tuple[str, str]]) -> Iterator[MotionClip]:
    from umf.data.mocap import load_mocap

    return load_mocap(path, problems)


LOADERS = {
    "bandai": _bandai_loader,
    "humanml3d": _humanml3d_loader,
    "interhuman": _interhuman_loader,
    "mocap": _mocap_loader,
}


def loader_of(name: str) -> Callable[[Path, list[tuple[str, str]]], Iterable[MotionClip]]:
    """The reader of a source: its name, or ``mocap-<folder>`` for a ``--mocap`` folder."""
    key = "mocap" if name == "mocap" or name.startswith("mocap-") else name
    if key not in LOADERS:
        raise UMFError(f"unknown source {name!r}")
    return LOADERS[key]


def mocap_sources(folders: Iterable[str | Path]) -> dict[str, Path]:
    """``--mocap`` folders as named sources (``mocap-<folder name>``, numbered if repeated)."""
    out: dict[str, Path] = {}
    for folder in folders:
        base = f"mocap-{re.sub(r'[^A-Za-z0-9_.-]+', '_', Path(folder).resolve().name) or 'dir'}"
        name, n = base, 2
        while name in out:
            name, n = f"{base}-{n}", n + 1
        out[name] = Path(folder)
    return out


# --------------------------------------------------------------------- corpus
@dataclass
class Corpus:
    """A prepared corpus on disk: clips, splits, scene recipes and normaliser."""

    root: Path
    manifest: dict[str, Any]
    clips: list[MotionClip]
    scenes: dict[str, list[dict[str, Any]]]
    _actors: dict[str, Actor] | None = field(default=None, repr=False)

    @classmethod
    def load(cls, root: str | Path) -> Corpus:
        root = Path(root)
        manifest_path = root / "manifest.json"
        if not manifest_path.exists():
            raise UMFError(f"{root}: not a umf corpus (no manifest.json); run `umf data prepare`")
        try:
            manifest = json.loads(manifest_path.read_text())
            if manifest.get("format") != FORMAT:
                raise UMFError(f"{manifest_path}: not a umf corpus manifest")
            if manifest.get("version") != FORMAT_VERSION:
                raise UMFError(
                    f"{root}: corpus format v{manifest.get('version')}, this umf reads "
                    f"v{FORMAT_VERSION}; run `umf data prepare` again"
                )
            clips = _load_clips(root / "clips.npz")
            scenes = json.loads((root / "scenes.json").read_text())
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            why = f"{type(exc).__name__}: {str(exc)[:120]}"
            raise UMFError(
                f"{root}: corrupt corpus ({why}); run `umf data prepare` again"
            ) from None
        return cls(root, manifest, clips, scenes)

    @property
    def normalizer(self) -> Normalizer:
        path = self.root / "normalizer.safetensors"
        try:
            norm = Normalizer.load(path)
        except Exception as exc:  # safetensors raises its own error types on a corrupt file
            raise UMFError(f"{path}: unreadable ({type(exc).__name__}); run `umf data prepare` "
                           "again") from None  # fmt: skip
        if norm.mean.shape != (262,) or not bool((norm.std > 0).all()):
            raise UMFError(f"{path}: not a 262-d normaliser with positive std")
        return norm

    def split_clips(self, split: str) -> list[MotionClip]:
        return [c for c in self.clips if c.split == split]

    def actors(self) -> dict[str, Actor]:
        """Single-person clips in their canonical frame, keyed by id (built once)."""
        if self._actors is None:
            self._actors = {c.id: _actor(c) for c in self.clips if c.num_people == 1}
        return self._actors

    def scene_joints(self, recipe: dict[str, Any]) -> np.ndarray:
        return build_scene(recipe, self.actors())

    def scene_features(self, recipe: dict[str, Any]) -> np.ndarray:
        """(P, T - 1, 262) features of a composed scene, in person 1's frame."""
        return build_scene_features(recipe, self.actors())

    def clip_features(self, clip: MotionClip) -> np.ndarray:
        """(P, T - 1, 262) features of a real clip in its person 1's canonical frame."""
        return clip_features(clip)

    def find(self, key: str) -> tuple[np.ndarray, str]:
        """(joints (P, T, 22, 3), caption) of a clip id or scene id."""
        for c in self.clips:
            if c.id == key:
                return c.joints, c.captions[0]
        for recipes in self.scenes.values():
            for r in recipes:
                if r["id"] == key:
                    return self.scene_joints(r), r["captions"][0]
        raise UMFError(f"no clip or scene {key!r} in {self.root}")


def _actor(c: MotionClip) -> Actor:
    return Actor.from_joints(
        c.id, c.joints[0], c.meta.get("content", ""), c.meta.get("style", ""),
        None if c.rot6d is None else c.rot6d[0],
    )  # fmt: skip


def clip_features(clip: MotionClip) -> np.ndarray:
    """(P, T - 1, 262) features of a clip in its person 1's canonical frame."""
    if clip.rot6d is None:
        raise ValueError(f"{clip.id}: no rotations; load clips through a corpus")
    scene, _ = canonicalize_scene(torch.from_numpy(clip.joints))
    rot = torch.from_numpy(clip.rot6d)
    return torch.stack([assemble_features(j, r) for j, r in zip(scene, rot, strict=True)]).numpy()


def _split_stats(clips: list[MotionClip], scenes: list[dict]) -> dict[str, Any]:
    frames = sum(c.num_frames * c.num_people for c in clips)
    scene_frames = sum(r["num_frames"] for r in scenes)
    sizes: dict[str, int] = {}
    relations: dict[str, int] = {}
    for r in scenes:
        sizes[str(r["num_people"])] = sizes.get(str(r["num_people"]), 0) + 1
        relations[r["relation"]] = relations.get(r["relation"], 0) + 1
    return {
        "clips": len(clips),
        "frames": frames,
        "hours": round(frames / FPS / 3600, 3),
        "scenes": len(scenes),
        "scene_frames": scene_frames,
        "scene_hours": round(scene_frames / FPS / 3600, 3),
        "scenes_by_size": sizes,
        "scenes_by_relation": relations,
    }


def fit_normalizer(
    clips: list[MotionClip],
    recipes: list[dict[str, Any]],
    actors: dict[str, Actor],
    max_frames: int,
    seed: int,
) -> Normalizer:
    """Mean/std of the features of train clips (canonical) and train scene persons.

    Items are visited in a seeded random order until ``max_frames`` frames are seen, so
    the cost stays bounded on large corpora.
    """
    items: list[tuple[str, Any]] = [("clip", c) for c in clips] + [("scene", r) for r in recipes]
    order = np.random.default_rng(seed).permutation(len(items))
    feats, seen = [], 0
    for i in order:
        kind, item = items[i]
        f = clip_features(item) if kind == "clip" else build_scene_features(item, actors)
        feats.append(torch.from_numpy(f.reshape(-1, f.shape[-1])))
        seen += feats[-1].shape[0]
        if seen >= max_frames:
            break
    return Normalizer.fit(torch.cat(feats))


def check_prepare_config(config: PrepareConfig) -> None:
    """Counts, fractions and sizes of ``data prepare`` (one-line errors, nothing written)."""
    from umf.validation import check_float, check_int

    check_int("--seed", config.seed, 0, 2**32 - 1)
    check_int("--train-scenes", config.train_scenes, 1, 1_000_000)
    for name in ("val_scenes", "test_scenes", "test_groups"):
        check_int(f"--{name.replace('_', '-')}", getattr(config, name), 0, 1_000_000)
    val = check_float("val_fraction", config.val_fraction, 0.0, 0.5)
    test = check_float("test_fraction", config.test_fraction, 0.0, 0.5)
    if val + test >= 1.0:
        raise UMFError("val_fraction + test_fraction must be below 1")
    if not config.group_sizes or any(not 3 <= g <= 16 for g in config.group_sizes):
        raise UMFError(f"group_sizes must lie in 3..16, got {config.group_sizes}")
    check_int("normalizer_max_frames", config.normalizer_max_frames, 1, 10**9)


def prepare_corpus(
    out: str | Path,
    sources: dict[str, str | Path],
    config: PrepareConfig | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Build (or reuse) a corpus in ``out`` from the given sources; returns the manifest."""
    config = config or PrepareConfig()
    out = Path(out)
    if not sources:
        raise UMFError("no data source given (use --bandai, --mocap, --humanml3d or --interhuman)")
    for name, path in sources.items():
        loader_of(name)
        if not Path(path).exists():
            raise UMFError(f"{name} data not found: {path}")
    from umf.validation import check_out_dir

    check_prepare_config(config)
    check_out_dir(out)
    t0 = time.perf_counter()
    fresh = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        return _prepare_into(out, sources, config, progress, log, t0, fresh)
    except BaseException:  # a bad captions.csv, Ctrl-C: a folder this run made goes too
        if fresh:
            shutil.rmtree(out, ignore_errors=True)
        raise


def _prepare_into(
    out: Path,
    sources: dict[str, Any],
    config: PrepareConfig,
    progress: bool,
    log: Callable[[str], None],
    t0: float,
    fresh: bool,
) -> dict[str, Any]:
    """:func:`prepare_corpus` once ``out`` exists (``fresh``: this run made it)."""
    # a corpus that worked keeps working until the new one is complete: every file is
    # written into a staging folder and moved into place at the end, the manifest last
    stage = out / f".staging-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    for old in out.glob(".staging-*"):  # left by a killed run
        shutil.rmtree(old, ignore_errors=True)
    remove_stale_temporaries(out)
    (out / "cache").mkdir(exist_ok=True)
    remove_stale_temporaries(out / "cache")
    cache_dir = out / "cache"
    problems: list[tuple[str, str]] = []
    clips: list[MotionClip] = []
    source_info = []
    for name, path in sources.items():
        got, reused = load_source(
            name, Path(path), loader_of(name), cache_dir, problems, progress, log
        )
        clips.extend(got)
        info = {"name": name, "path": str(path), "clips": len(got), "reused_cache": reused}
        if Path(path).is_dir():  # a library's terms travel with it (LICENSE*, README*)
            terms = ("LICENSE", "README", "SOURCE-README")
            info["license_files"] = sorted(
                p.name for p in Path(path).iterdir() if p.name.upper().startswith(terms)
            )
        source_info.append(info)
        log(f"{name}: {len(got)} clips" + (" (cached)" if reused else ""))
    for origin, reason in problems:
        log(f"skipped {origin}: {reason}")
    if not clips:  # leave nothing behind: a folder this run made, or its empty caches
        if fresh:
            shutil.rmtree(out, ignore_errors=True)
        else:
            for name in sources:
                for cache in cache_dir.glob(f"{name}-*.npz"):
                    cache.unlink(missing_ok=True)
        raise UMFError("no readable clip in the given sources")

    index = [{"id": c.id, "source": c.source, "split": c.split, **c.meta} for c in clips]
    splits = assign_splits(index, config.val_fraction, config.test_fraction)
    for c in clips:
        c.split = splits[c.id]

    # scenes: two-person scenes per split, held-out groups of 3..6 from test clips
    scenes: dict[str, list[dict]] = {}
    counts = {"train": config.train_scenes, "val": config.val_scenes, "test": config.test_scenes}
    singles = {s: [c for c in clips if c.split == s and c.num_people == 1] for s in SPLITS}
    actors = {s: [_actor(c) for c in singles[s]] for s in SPLITS}
    for i, s in enumerate(SPLITS):
        scenes[s] = compose_corpus(actors[s], counts[s], (2,), seed=config.seed + i)
        for r in scenes[s]:
            r["id"] = f"{s}-{r['id']}"
    groups = compose_corpus(
        actors["test"], config.test_groups, config.group_sizes, seed=config.seed + 7
    )
    for r in groups:
        r["id"] = f"group-{r['id']}"
    scenes["test_groups"] = groups
    log("scenes: " + ", ".join(f"{k} {len(v)}" for k, v in scenes.items()))

    by_id = {a.id: a for s in SPLITS for a in actors[s]}
    normalizer = fit_normalizer(
        [c for c in clips if c.split == "train"], scenes["train"], by_id,
        config.normalizer_max_frames, config.seed,
    )  # fmt: skip

    stage.mkdir()
    try:
        manifest = _write_corpus(
            stage, clips, scenes, normalizer, config, source_info, problems, t0
        )
        for f in ("clips.npz", "clips.json", "scenes.json", "normalizer.safetensors",
                  "manifest.json"):  # fmt: skip
            os.replace(stage / f, out / f)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return manifest


def _write_corpus(out: Path, clips, scenes, normalizer, config, source_info, problems,
                  t0: float) -> dict[str, Any]:  # fmt: skip
    """Every file of a corpus into ``out``; returns the manifest."""
    _save_clips(out / "clips.npz", clips)
    write_json_atomic(out / "clips.json", [
        {"id": c.id, "source": c.source, "split": c.split, "captions": c.captions,
         "num_people": c.num_people, "num_frames": c.num_frames, **c.meta}
        for c in clips
    ])  # fmt: skip
    write_json_atomic(out / "scenes.json", scenes)
    normalizer.save(out / "normalizer.safetensors")
    stats = {s: _split_stats([c for c in clips if c.split == s], scenes.get(s, [])) for s in SPLITS}
    stats["test_groups"] = _split_stats([], scenes["test_groups"])
    manifest = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "umf_version": __version__,
        "fps": FPS,
        "seed": config.seed,
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(config).items()},
        "sources": source_info,
        "skipped": [{"file": o, "reason": r} for o, r in problems],
        "splits": stats,
        "total": {
            "clips": len(clips),
            "frames": sum(c.num_frames * c.num_people for c in clips),
            "hours": round(sum(c.num_frames * c.num_people for c in clips) / FPS / 3600, 3),
        },
        "seconds": round(time.perf_counter() - t0, 1),
        "license": "Derived from CC BY-NC 4.0 data where the source is Bandai: "
        + BANDAI_ATTRIBUTION
        + (
            "; mocap libraries under their own terms (each source's license_files)"
            if any(s["name"].startswith("mocap") for s in source_info)
            else ""
        ),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json_atomic(out / "manifest.json", manifest)
    return manifest
