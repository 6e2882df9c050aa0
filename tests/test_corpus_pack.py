"""scripts/corpus_pack.py: a packed corpus unpacks to the same motion within its steps."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from conftest import prepare_fixture_corpus
from umf.data.corpus import Corpus

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "corpus_pack.py"


def _load_script():
    spec = importlib.util.spec_from_file_location("corpus_pack", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pack_unpack_round_trip(tmp_path):
    cp = _load_script()
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
