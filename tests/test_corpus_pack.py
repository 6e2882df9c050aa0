"""scripts/corpus_pack.py: a packed corpus unpacks to the same motion within its steps."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script, prepare_fixture_corpus
from umf.data.corpus import Corpus


def test_pack_unpack_round_trip(tmp_path):
    cp = load_script("corpus_pack")
    src = prepare_fixture_corpus(tmp_path / "corpus", train_scenes=6, val_scenes=2,
                                 test_scenes=2, test_groups=2)  # fmt: skip
    cp.pack(src, tmp_path / "packed")
    assert not (tmp_path / "packed" / "text.npz").exists()  # no text cache yet: skipped
    cp.unpack(tmp_path / "packed", tmp_path / "unpacked")
    a, b = Corpus.load(src), Corpus.load(tmp_path / "unpacked")
    assert [c.id for c in a.clips] == [c.id for c in b.clips]
    assert a.scenes == b.scenes and a.manifest == b.manifest
    for ca, cb in zip(a.clips, b.clips, strict=True):
        assert np.abs(ca.joints - cb.joints).max() <= cp.JOINT_STEP / 2 + 1e-6
        assert np.abs(ca.rot6d - cb.rot6d).max() <= cp.ROT_STEP / 2 + 1e-6
    assert (src / "normalizer.safetensors").read_bytes() == (
        tmp_path / "unpacked" / "normalizer.safetensors"
    ).read_bytes()


def test_coarse_steps_travel_in_the_pack(tmp_path):
    """A pack made with coarser steps unpacks with them (not the module's defaults)."""
    cp = load_script("corpus_pack")
    src = prepare_fixture_corpus(tmp_path / "corpus", train_scenes=3, val_scenes=1,
                                 test_scenes=1, test_groups=1)  # fmt: skip
    js, rs = 4 * cp.JOINT_STEP, 4 * cp.ROT_STEP
    cp.pack(src, tmp_path / "packed", joint_step=js, rot_step=rs)
    cp.unpack(tmp_path / "packed", tmp_path / "unpacked")
    a, b = Corpus.load(src), Corpus.load(tmp_path / "unpacked")
    pairs = list(zip(a.clips, b.clips, strict=True))
    err_j = max(np.abs(ca.joints - cb.joints).max() for ca, cb in pairs)
    err_r = max(np.abs(ca.rot6d - cb.rot6d).max() for ca, cb in pairs)
    assert err_j <= js / 2 + 1e-6 and err_r <= rs / 2 + 1e-6
    assert err_j > cp.JOINT_STEP / 2  # decoded at the pack's step, not the default's


def test_text_features_travel_as_int8(tmp_path):
    """``text_int8`` halves the text pack; every unpacked feature row stays within half a
    quantisation step (max |row| / 254, plus float16 rounding) of the cached one."""
    from safetensors.numpy import load_file

    from umf.config import small_config
    from umf.train.run import text_cache

    cp = load_script("corpus_pack")
    src = prepare_fixture_corpus(tmp_path / "corpus", train_scenes=3, val_scenes=1,
                                 test_scenes=1, test_groups=1)  # fmt: skip
    text_cache(small_config(), Corpus.load(src), progress=False)
    cp.pack(src, tmp_path / "f16")
    cp.pack(src, tmp_path / "q8", text_int8=True)
    assert (tmp_path / "q8" / "text.npz").stat().st_size < (
        0.75 * (tmp_path / "f16" / "text.npz").stat().st_size
    )
    cp.unpack(tmp_path / "q8", tmp_path / "unpacked")
    cached = sorted((src / "text-cache").rglob("*.safetensors"))
    assert cached
    for path in cached:
        a = load_file(str(path))
        b = load_file(
            str(tmp_path / "unpacked" / "text-cache" / path.relative_to(src / "text-cache"))
        )
        for key in ("tokens", "pooled"):
            x, y = np.atleast_2d(a[key]), np.atleast_2d(b[key])
            step = np.abs(x).max(axis=1, keepdims=True) / 127
            assert np.all(np.abs(x - y) <= 0.5 * step * 1.01 + 1e-3 * step + 1e-6), (path, key)


def test_packs_without_steps_unpack_at_the_old_defaults(tmp_path):
    """Packs written before the steps travelled (no ``steps`` entry) still unpack."""
    cp = load_script("corpus_pack")
    src = prepare_fixture_corpus(tmp_path / "corpus", train_scenes=3, val_scenes=1,
                                 test_scenes=1, test_groups=1)  # fmt: skip
    cp.pack(src, tmp_path / "packed")
    path = tmp_path / "packed" / "motion.npz"
    with np.load(path) as z:
        old = {k: z[k] for k in z.files if k != "steps"}
    np.savez(path, **old)
    cp.unpack(tmp_path / "packed", tmp_path / "unpacked")
    a, b = Corpus.load(src), Corpus.load(tmp_path / "unpacked")
    for ca, cb in zip(a.clips, b.clips, strict=True):
        assert np.abs(ca.joints - cb.joints).max() <= cp.JOINT_STEP / 2 + 1e-6


def test_split_parts_join_back_byte_for_byte(tmp_path):
    """A pack too large for one carry travels in parts; joined, every file is as it was."""
    cp = load_script("corpus_pack")
    packed = tmp_path / "packed"
    packed.mkdir()
    rng = np.random.default_rng(0)
    files = {"motion.npz": rng.bytes(10_001), "text.npz": rng.bytes(7), "empty.bin": b""}
    for name, data in files.items():
        (packed / name).write_bytes(data)
    parts = cp.split(packed, tmp_path / "carry", 3)
    assert [p.name for p in parts] == ["part1", "part2", "part3"]
    sizes = [sum(f.stat().st_size for f in p.iterdir() if f.suffix != ".json") for p in parts]
    assert max(sizes) - min(sizes) <= len(files)  # about equal parts
    cp.join(tmp_path / "joined", parts[2], parts[0], parts[1])  # any order
    for name, data in files.items():
        assert (tmp_path / "joined" / name).read_bytes() == data


def test_join_refuses_a_missing_or_damaged_part(tmp_path):
    cp = load_script("corpus_pack")
    packed = tmp_path / "packed"
    packed.mkdir()
    (packed / "motion.npz").write_bytes(bytes(range(256)) * 4)
    one, two = cp.split(packed, tmp_path / "carry", 2)
    with pytest.raises(SystemExit, match="missing part"):
        cp.join(tmp_path / "joined", one)
    piece = two / "motion.npz.2"
    piece.write_bytes(b"x" + piece.read_bytes()[1:])
    with pytest.raises(SystemExit, match="do not match"):
        cp.join(tmp_path / "joined", one, two)


def test_split_refuses_old_parts_and_join_refuses_mixed_splits(tmp_path):
    cp = load_script("corpus_pack")
    packed = tmp_path / "packed"
    packed.mkdir()
    (packed / "motion.npz").write_bytes(b"first pack")
    first = cp.split(packed, tmp_path / "a", 2)
    with pytest.raises(SystemExit, match="not empty"):
        cp.split(packed, tmp_path / "a", 2)
    (packed / "motion.npz").write_bytes(b"second pack, longer")
    second = cp.split(packed, tmp_path / "b", 2)
    with pytest.raises(SystemExit, match="different splits"):
        cp.join(tmp_path / "joined", first[0], second[1])
    assert not (tmp_path / "joined").exists()  # nothing written before the checks pass
