"""scripts/model_variant.py: the same weights under other decoding or sampling options."""

from __future__ import annotations

import json

import pytest

from conftest import load_script, save_tiny_model
from umf.errors import UMFError
from umf.eval.plan import model_label
from umf.pipeline import UMFPipeline


def test_a_variant_decodes_with_its_options_and_keeps_the_weights(tmp_path):
    mv = load_script("model_variant")
    src = save_tiny_model(tmp_path / "src")
    dst = mv.write_variant(
        src, tmp_path / "v", ["vae.root_fusion=0.001", "vae.reaction_root_fusion=null"], "rf001"
    )
    pipe = UMFPipeline.from_pretrained(dst)
    assert pipe.config.vae.root_fusion == 0.001 and pipe.config.vae.reaction_root_fusion is None
    for f in src.iterdir():  # every other file byte-identical
        if f.name not in ("config.json", "format.json"):
            assert (dst / f.name).read_bytes() == f.read_bytes()
    assert model_label(dst) == "rf001"
    fmt = json.loads((dst / "format.json").read_text())
    assert fmt["variant_of"]["options"][0] == "vae.root_fusion=0.001"
    # the source is untouched: its own options, its own name
    assert UMFPipeline.from_pretrained(src).config.vae.root_fusion != 0.001
    with pytest.raises(UMFError, match="exists"):
        mv.write_variant(src, dst, [])
    with pytest.raises(UMFError, match="root_fusion"):  # checked before anything is written
        mv.write_variant(src, tmp_path / "bad", ["vae.root_fusion=oops"])
    with pytest.raises(UMFError, match="fine_guidance must be between 0"):
        mv.write_variant(src, tmp_path / "bad", ["pflow.fine_guidance=-1"])
    with pytest.raises(UMFError, match="starts"):  # a pyramid the model cannot build
        mv.write_variant(src, tmp_path / "bad", ["pflow.starts=[0.2,0.5]"])
    with pytest.raises(UMFError, match="shape"):  # options the weights cannot take
        mv.write_variant(src, tmp_path / "bad", ["vae.d_model=64"])
    with pytest.raises(UMFError, match="not a model directory"):
        mv.write_variant(tmp_path, tmp_path / "bad", [])
    assert not (tmp_path / "bad").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
