"""Pack a prepared corpus (and its text cache) small enough to carry to a training machine.

A GPU node often has neither the raw motion archives nor the text encoder's weights, and
what can be copied to it may be capped. ``pack`` stores the corpus's joints (1 mm steps)
and rotations (5e-4 steps, under 0.02 degree) as per-clip time differences compressed with
LZMA (about 10x smaller than ``clips.npz``), and the text cache's features in float16;
``unpack`` rebuilds a corpus directory that ``Corpus.load`` and ``umf train`` read, with
the cache's ``encoder.json`` so training runs without the encoder installed.

    python scripts/corpus_pack.py pack out/corpus .gpu              # motion.npz, text.npz
    python scripts/corpus_pack.py pack out/corpus .gpu coarse   # 2 mm, 1e-3, int8 text
    python scripts/corpus_pack.py unpack .gpu out/corpus            # on the other machine
    python scripts/corpus_pack.py check out/corpus out/unpacked     # largest differences

When the working tree and a pack together exceed what one call may carry, ``split`` cuts
the pack's files into N parts of about equal size, part k in ``DST/partk`` (the first call
carries part1 and stashes it on the machine, the next carries part2, ...), and ``join``
puts them back together, checking each file's SHA-256 against the manifest every part
holds:

    python scripts/corpus_pack.py split .gpu/all .gpu 2             # .gpu/part1, .gpu/part2
    python scripts/corpus_pack.py join .gpu/text /tmp/stash/part1 .gpu/part2   # any order
"""

from __future__ import annotations

import argparse
import hashlib
import json
import lzma
from pathlib import Path

import numpy as np

JOINT_STEP = 1e-3  # metres
ROT_STEP = 5e-4  # rotation-matrix entries (error under 0.02 degree)
CORPUS_FILES = ("manifest.json", "scenes.json", "normalizer.safetensors", "clips.json")


def _track_starts(index: list[dict]) -> np.ndarray:
    """Row of each person's first frame in the concatenated arrays."""
    starts, pos = [], 0
    for e in index:
        for _ in range(e["num_people"]):
            starts.append(pos)
            pos += e["num_frames"]
    return np.asarray(starts, dtype=np.int64)


def encode_tracks(x: np.ndarray, step: float, starts: np.ndarray) -> bytes:
    """Quantise, take differences along time within each track, compress (channel-major)."""
    q = np.round(x.reshape(len(x), -1) / step).astype(np.int64)
    d = q.copy()
    d[1:] -= q[:-1]
    d[starts] = q[starts]
    if np.abs(d).max() >= 2**15:
        raise ValueError("a frame-to-frame change does not fit in int16; use a coarser step")
    return lzma.compress(np.ascontiguousarray(d.T.astype(np.int16)).tobytes(), preset=6)


def decode_tracks(blob: bytes, shape: tuple[int, ...], step: float, starts: np.ndarray):
    n = shape[0]
    d = np.frombuffer(lzma.decompress(blob), dtype=np.int16).reshape(-1, n).T.astype(np.int64)
    ends = np.append(starts[1:], n)
    q = np.empty_like(d)
    for s, e in zip(starts, ends, strict=True):
        q[s:e] = np.cumsum(d[s:e], axis=0)
    return (q * step).astype(np.float32).reshape(shape)


def pack(
    corpus: Path,
    out: Path,
    joint_step: float = JOINT_STEP,
    rot_step: float = ROT_STEP,
    text_int8: bool = False,
) -> None:
    """The steps (and the text's quantisation) travel in the pack: ``unpack`` reads any."""
    out.mkdir(parents=True, exist_ok=True)
    with np.load(corpus / "clips.npz") as z:
        joints, rot6d, index_s = z["joints"], z["rot6d"], str(z["index"])
    starts = _track_starts(json.loads(index_s))
    files = {f: _z((corpus / f).read_bytes()) for f in CORPUS_FILES if (corpus / f).exists()}
    np.savez(
        out / "motion.npz",
        joints=np.frombuffer(encode_tracks(joints, joint_step, starts), np.uint8),
        rot6d=np.frombuffer(encode_tracks(rot6d, rot_step, starts), np.uint8),
        steps=np.asarray([joint_step, rot_step]),
        shapes=np.array(json.dumps({"joints": joints.shape, "rot6d": rot6d.shape})),
        index=_z(index_s.encode()),
        names=np.array(json.dumps(list(files))),
        **{f"file{i}": v for i, v in enumerate(files.values())},
    )
    _pack_text(corpus, out / "text.npz", int8=text_int8)


def _z(data: bytes) -> np.ndarray:
    return np.frombuffer(lzma.compress(data, preset=6), np.uint8)


def _unz(a: np.ndarray) -> bytes:
    return lzma.decompress(a.tobytes())


def quantise_rows(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """int8 per row with a float16 scale (max |x| / 127): half of float16's bytes."""
    scale = (np.abs(x).max(axis=1) / 127.0).astype(np.float16)
    safe = np.where(scale > 0, scale.astype(np.float32), 1.0)[:, None]
    return np.round(x / safe).clip(-127, 127).astype(np.int8), scale


def _pack_text(corpus: Path, out: Path, int8: bool = False) -> None:
    """The cached features of every caption training asks for (nothing else); ``int8``
    stores them quantised per row (error under half a step of max |row| / 127)."""
    from safetensors import safe_open

    from umf.data.corpus import Corpus
    from umf.text import CachedTextEncoder, TextFeatureCache
    from umf.train.run import corpus_captions

    cache = corpus / "text-cache"
    if not (cache / "encoder.json").exists():
        print(f"{cache}: no encoder.json (a flow stage writes it): text features not packed")
        return
    lookup = TextFeatureCache(CachedTextEncoder.load(cache), cache)
    rel, meta, tokens, pooled, lengths = [], [], [], [], []
    loaded = Corpus.load(corpus)
    needed = corpus_captions(loaded)
    # respelled captions (train_*.respell_captions) travel when a run here encoded them
    extra = sorted(set(corpus_captions(loaded, respell=True)) - set(needed))
    for text in needed + [t for t in extra if lookup.path_of(t).exists()]:
        path = lookup.path_of(text)
        if not path.exists():
            raise SystemExit(f"{cache}: no features for {text!r}; run the flow stage once")
        with safe_open(str(path), framework="numpy") as fh:
            rel.append(str(path.relative_to(cache)))
            meta.append(fh.metadata())
            t = fh.get_tensor("tokens")
            tokens.append(t.astype(np.float32))
            pooled.append(fh.get_tensor("pooled").astype(np.float32))
            lengths.append(t.shape[0])
    tok, pool, scales = np.concatenate(tokens), np.stack(pooled), {}
    if int8:
        tok, scales["tok_scale"] = quantise_rows(tok)
        pool, scales["pool_scale"] = quantise_rows(pool)
    else:
        tok, pool = tok.astype(np.float16), pool.astype(np.float16)
    blob = lzma.compress(tok.tobytes() + pool.tobytes(), preset=6)
    np.savez(
        out, blob=np.frombuffer(blob, np.uint8), lengths=np.asarray(lengths),
        dim=np.asarray(pooled[0].shape[0]), rel=np.array(json.dumps(rel)),
        meta=np.array(json.dumps(meta)), encoder=np.array((cache / "encoder.json").read_text()),
        **scales,
    )  # fmt: skip


def unpack(packed: Path, corpus: Path) -> None:
    """Whichever of motion.npz and text.npz ``packed`` holds (they may travel apart)."""
    corpus.mkdir(parents=True, exist_ok=True)
    if (packed / "motion.npz").exists():
        _unpack_motion(packed / "motion.npz", corpus)
    if (packed / "text.npz").exists():
        _unpack_text(packed / "text.npz", corpus / "text-cache")


def _unpack_motion(packed: Path, corpus: Path) -> None:
    with np.load(packed) as z:
        shapes = json.loads(str(z["shapes"]))
        index_s = _unz(z["index"]).decode()
        starts = _track_starts(json.loads(index_s))
        j_step, r_step = z["steps"] if "steps" in z.files else (JOINT_STEP, ROT_STEP)
        joints = decode_tracks(z["joints"].tobytes(), tuple(shapes["joints"]), j_step, starts)
        rot6d = decode_tracks(z["rot6d"].tobytes(), tuple(shapes["rot6d"]), r_step, starts)
        for i, name in enumerate(json.loads(str(z["names"]))):
            (corpus / name).write_bytes(_unz(z[f"file{i}"]))
    np.savez(corpus / "clips.npz", joints=joints, rot6d=rot6d, index=np.array(index_s))


def _unpack_text(packed: Path, cache: Path) -> None:
    from safetensors.numpy import save_file

    with np.load(packed) as z:
        lengths, dim = z["lengths"], int(z["dim"])
        raw = lzma.decompress(z["blob"].tobytes())
        n_tok = int(lengths.sum())
        if "tok_scale" in z.files:  # int8 rows with float16 scales
            q = np.frombuffer(raw, np.int8).astype(np.float32)
            tok_scale = z["tok_scale"].astype(np.float32)[:, None]
            tokens = q[: n_tok * dim].reshape(n_tok, dim) * tok_scale
            pooled = q[n_tok * dim :].reshape(-1, dim) * z["pool_scale"].astype(np.float32)[:, None]
        else:
            tokens = np.frombuffer(raw[: n_tok * dim * 2], np.float16).reshape(n_tok, dim)
            pooled = np.frombuffer(raw[n_tok * dim * 2 :], np.float16).reshape(-1, dim)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        for i, (rel, meta) in enumerate(zip(json.loads(str(z["rel"])), json.loads(str(z["meta"])),
                                            strict=True)):  # fmt: skip
            path = cache / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            arrays = {"tokens": tokens[offsets[i] : offsets[i + 1]].astype(np.float32),
                      "pooled": pooled[i].astype(np.float32)}  # fmt: skip
            save_file(arrays, str(path), metadata=meta)
        (cache / "encoder.json").write_text(str(z["encoder"]))


SPLIT_MANIFEST = "parts.json"


def split(packed: Path, out: Path, parts: int) -> list[Path]:
    """Cut every file of ``packed`` into ``parts`` byte ranges: part k (1-based) holds range
    k of each file as ``NAME.k`` and the manifest (sizes and SHA-256 of the whole files).
    The part directories must be new or empty (old parts would mix with the new ones)."""
    if parts < 1:
        raise SystemExit("split needs at least one part")
    files = sorted(f for f in packed.iterdir() if f.is_file())
    dirs = [out / f"part{k}" for k in range(1, parts + 1)]
    used = [d for d in dirs if d.exists() and any(d.iterdir())]
    if used:
        raise SystemExit(f"{used[0]} is not empty: remove the old parts first")
    manifest = {"parts": parts, "files": {}}
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
    for f in files:
        data = f.read_bytes()
        manifest["files"][f.name] = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        bounds = [len(data) * k // parts for k in range(parts + 1)]
        for k, d in enumerate(dirs):
            (d / f"{f.name}.{k + 1}").write_bytes(data[bounds[k] : bounds[k + 1]])
    for d in dirs:
        (d / SPLIT_MANIFEST).write_text(json.dumps(manifest, indent=1))
    return dirs


def join(out: Path, *part_dirs: Path) -> None:
    """Reassemble the files that :func:`split` cut, from part directories in any order;
    every file is checked against the manifest before any is written."""
    if not part_dirs:
        raise SystemExit("join needs the part directories")
    found: dict[str, Path] = {}
    manifests = []
    for d in part_dirs:
        for f in d.iterdir():
            if f.name == SPLIT_MANIFEST:
                manifests.append(json.loads(f.read_text()))
            else:
                found[f.name] = f
    if not manifests:
        raise SystemExit(f"no {SPLIT_MANIFEST} in {', '.join(map(str, part_dirs))}")
    if any(m != manifests[0] for m in manifests):
        raise SystemExit("the parts come from different splits (their manifests differ)")
    manifest, joined = manifests[0], {}
    for name, info in manifest["files"].items():
        pieces = [found.get(f"{name}.{k}") for k in range(1, manifest["parts"] + 1)]
        missing = [f"{name}.{k}" for k, p in enumerate(pieces, 1) if p is None]
        if missing:
            raise SystemExit(f"missing part(s) {', '.join(missing)}")
        data = b"".join(p.read_bytes() for p in pieces)
        if len(data) != info["size"] or hashlib.sha256(data).hexdigest() != info["sha256"]:
            raise SystemExit(f"{name}: the joined parts do not match the manifest")
        joined[name] = data
    out.mkdir(parents=True, exist_ok=True)
    for name, data in joined.items():
        (out / name).write_bytes(data)


def check(a: Path, b: Path) -> None:
    with np.load(a / "clips.npz") as za, np.load(b / "clips.npz") as zb:
        for k in ("joints", "rot6d"):
            print(f"{k}: max |difference| {np.abs(za[k] - zb[k]).max():.2e}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("pack", help="corpus -> motion.npz, text.npz")
    p.add_argument("src", type=Path)
    p.add_argument("dst", type=Path)
    p.add_argument("coarse", nargs="?", choices=["coarse"], help="when the carry cap is tight")
    for name, help_ in (("unpack", "pack -> corpus"), ("check", "largest differences")):
        p = sub.add_parser(name, help=help_)
        p.add_argument("src", type=Path)
        p.add_argument("dst", type=Path)
    p = sub.add_parser("split", help="a pack's files in N parts")
    p.add_argument("src", type=Path)
    p.add_argument("dst", type=Path)
    p.add_argument("parts", nargs="?", type=int, default=2)
    p = sub.add_parser("join", help="the parts back into whole files")
    p.add_argument("dst", type=Path)
    p.add_argument("parts", nargs="+", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "pack" and a.coarse:
        pack(a.src, a.dst, joint_step=2 * JOINT_STEP, rot_step=2 * ROT_STEP, text_int8=True)
    elif a.cmd == "split":
        split(a.src, a.dst, a.parts)
    elif a.cmd == "join":
        join(a.dst, *a.parts)
    else:
        {"pack": pack, "unpack": unpack, "check": check}[a.cmd](a.src, a.dst)


if __name__ == "__main__":
    main()
