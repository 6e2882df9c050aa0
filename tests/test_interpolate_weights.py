"""scripts/interpolate_weights.py: a flow's weights between a model's and its fine-tune's."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from conftest import save_tiny_model
from umf.errors import UMFError

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "interpolate_weights.py"
spec = importlib.util.spec_from_file_location("interpolate_weights", SCRIPT)
iw = importlib.util.module_from_spec(spec)
spec.loader.exec_module(iw)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("interp")
    return save_tiny_model(root / "base", seed=1), save_tiny_model(root / "tuned", seed=2)


def test_the_ends_are_the_two_models_and_the_middle_their_mean(pair, tmp_path):
    base, tuned = pair
    a, b = (load_file(str(d / "pflow.safetensors")) for d in (base, tuned))
    for alpha, want in ((0.0, a), (1.0, b)):
        out = iw.write_interpolated(base, tuned, tmp_path / f"m{alpha}", alpha)
        got = load_file(str(out / "pflow.safetensors"))
        assert all(torch.equal(got[k], want[k]) for k in want)
    mid = iw.write_interpolated(base, tuned, tmp_path / "mid", 0.5, name="halfway")
    got = load_file(str(mid / "pflow.safetensors"))
    k = next(k for k in a if a[k].is_floating_point() and not torch.equal(a[k], b[k]))
    want = ((a[k].float() + b[k].float()) / 2).to(a[k].dtype)
    torch.testing.assert_close(got[k], want, atol=1e-3, rtol=1e-3)
    for other in ("vae", "sflow"):  # the rest is the base's
        assert (mid / f"{other}.safetensors").read_bytes() == (
            base / f"{other}.safetensors"
        ).read_bytes()
    fmt = json.loads((mid / "format.json").read_text())
    assert fmt["name"] == "halfway" and fmt["interpolated"]["alpha"] == 0.5
    assert fmt["interpolated"]["module"] == "pflow"


def test_bad_requests_are_one_line_errors_and_write_nothing(pair, tmp_path):
    base, tuned = pair
    with pytest.raises(UMFError, match="alpha must lie"):
        iw.write_interpolated(base, tuned, tmp_path / "x", 1.5)
    with pytest.raises(UMFError, match="module must be"):
        iw.write_interpolated(base, tuned, tmp_path / "x", 0.5, module="text")
    with pytest.raises(UMFError, match="not a model directory"):
        iw.write_interpolated(base, tmp_path, tmp_path / "x", 0.5)
    assert not (tmp_path / "x").exists()
    (tmp_path / "taken").mkdir()
    with pytest.raises(UMFError, match="exists"):
        iw.write_interpolated(base, tuned, tmp_path / "taken", 0.5)
    with pytest.raises(UMFError, match="differ in"):
        iw.interpolate({"w": torch.ones(2)}, {"v": torch.ones(2)}, 0.5)
    with pytest.raises(UMFError, match=r"\(2,\) against \(3,\)"):
        iw.interpolate({"w": torch.ones(2)}, {"w": torch.ones(3)}, 0.5)
