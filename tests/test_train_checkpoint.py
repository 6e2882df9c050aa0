import json
from pathlib import Path

import pytest
import torch
from torch import nn

from umf import checkpoint as C
from umf.errors import UMFError
from umf.representation import FEATURE_DIM, Normalizer


def _net(seed: int = 0, width: int = 16) -> nn.Module:
    torch.manual_seed(seed)
    return nn.Sequential(nn.Linear(4, width), nn.LayerNorm(width), nn.Linear(width, 3))


def _normalizer() -> Normalizer:
    return Normalizer(torch.randn(FEATURE_DIM), torch.rand(FEATURE_DIM) + 0.5)


def _trained_optimizer(net: nn.Module) -> torch.optim.Optimizer:
    opt = torch.optim.AdamW(net.parameters(), lr=1e-2)
    for _ in range(3):
        opt.zero_grad()
        net(torch.randn(5, 4)).pow(2).mean().backward()
        opt.step()
    return opt


def _same(a: nn.Module, b: nn.Module) -> bool:
    pairs = zip(a.state_dict().values(), b.state_dict().values(), strict=True)
    return all(torch.equal(x, y) for x, y in pairs)


def test_round_trip(tmp_path):
    net, frozen, norm = _net(0), _net(1, 8), _normalizer()
    opt = _trained_optimizer(net)
    path = C.save_checkpoint(
        tmp_path / "last",
        {"denoiser": net, "vae": frozen},
        config={"family": "small", "vae": {"d_model": 8}},
        normalizer=norm,
        state={"step": 3, "best_val": 0.5},
        optimizer=opt.state_dict(),
        scheduler={"last_epoch": 3},
    )
    names = sorted(p.name for p in path.iterdir())
    assert names == [
        "config.json", "denoiser.safetensors", "format.json", "normalizer.safetensors",
        "trainer_state.pt", "vae.safetensors",
    ]  # fmt: skip
    info = json.loads((path / "format.json").read_text())
    assert info["format"] == "umf-checkpoint" and info["version"] == 1 and info["step"] == 3

    net2, frozen2 = _net(5), _net(6, 8)
    ck = C.load_checkpoint(path, {"denoiser": net2, "vae": frozen2}, trainer_state=True)
    assert _same(net, net2) and _same(frozen, frozen2)
    assert ck.config["vae"]["d_model"] == 8 and ck.step == 3
    torch.testing.assert_close(ck.normalizer.mean, norm.mean)
    opt2 = torch.optim.AdamW(net2.parameters(), lr=1e-2)
    opt2.load_state_dict(ck.optimizer)
    for s1, s2 in zip(opt.state.values(), opt2.state.values(), strict=True):
        torch.testing.assert_close(s1["exp_avg"], s2["exp_avg"])
    assert ck.scheduler == {"last_epoch": 3} and ck.state["best_val"] == 0.5
    # modules not asked for are returned as state dicts
    only = C.load_checkpoint(path, {"vae": _net(7, 8)})
    assert set(only.weights) == {"denoiser"} and only.optimizer is None


def test_overwrite_keeps_a_single_directory(tmp_path):
    for seed in range(3):
        C.save_checkpoint(tmp_path / "last", {"net": _net(seed)}, state={"step": seed})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last"]
    net = _net(9)
    assert C.load_checkpoint(tmp_path / "last", {"net": net}, trainer_state=True).step == 2
    assert _same(net, _net(2))


def test_bad_checkpoints_give_one_line_errors(tmp_path):
    path = C.save_checkpoint(tmp_path / "ck", {"net": _net()}, state={"step": 1})

    def err(modules=None, target=path, **kw) -> str:
        with pytest.raises(UMFError) as exc:
            C.load_checkpoint(target, modules, **kw)
        msg = str(exc.value)
        assert "\n" not in msg
        return msg

    assert "no checkpoint" in err(target=tmp_path / "nowhere")
    assert "missing module file other.safetensors" in err({"other": _net()})
    assert "tensor net.0.weight has shape (16, 4)" in err({"net": _net(width=32)})
    assert "unexpected tensor" in err({"net": nn.Sequential(nn.Linear(4, 16))})
    C.load_checkpoint(path, {"net": nn.Sequential(nn.Linear(4, 16))}, strict=False)

    (path / "trainer_state.pt").write_bytes(b"not a zip")
    assert "corrupt trainer state" in err(trainer_state=True)
    (path / "net.safetensors").write_bytes(b"\x00garbage" * 10)
    assert "corrupt module file" in err({"net": _net()})

    info = json.loads((path / "format.json").read_text())
    (path / "format.json").write_text(json.dumps({**info, "version": 99}))
    assert "format v99, this umf reads v1" in err()
    (path / "format.json").write_text("{")
    assert "corrupt" in err()
    (path / "format.json").unlink()
    assert "not a umf checkpoint" in err()


def test_failed_load_leaves_modules_untouched(tmp_path):
    path = C.save_checkpoint(tmp_path / "ck", {"a": _net(0), "b": _net(1)})
    a, b = _net(5), _net(6, width=8)  # b does not fit
    with pytest.raises(UMFError, match=r"b\.0\.weight"):
        C.load_checkpoint(path, {"a": a, "b": b})
    assert _same(a, _net(5))


def test_crash_mid_save_keeps_previous_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "last"
    C.save_checkpoint(path, {"a": _net(0), "b": _net(1)}, state={"step": 10})
    real = C._write_module
    calls = []

    def crash_on_second(*args, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt("killed")
        return real(*args, **kw)

    monkeypatch.setattr(C, "_write_module", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        C.save_checkpoint(path, {"a": _net(2), "b": _net(3)}, state={"step": 20})
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last"]  # no temporary left
    a, b = _net(8), _net(9)
    assert C.load_checkpoint(path, {"a": a, "b": b}, trainer_state=True).step == 10
    assert _same(a, _net(0)) and _same(b, _net(1))


def test_crash_between_renames_is_recovered(tmp_path):
    path = tmp_path / "last"
    C.save_checkpoint(path, {"a": _net(0)}, state={"step": 10})
    path.rename(tmp_path / ".last.old-abc123")  # killed after moving the old one aside
    a = _net(5)
    assert C.load_checkpoint(path, {"a": a}, trainer_state=True).step == 10
    assert _same(a, _net(0))
    C.save_checkpoint(path, {"a": _net(1)}, state={"step": 20})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last"]
    assert C.load_checkpoint(path, {"a": a}, trainer_state=True).step == 20


def test_fp16_export(tmp_path):
    net, norm = _net(0, width=64), _normalizer()
    src = C.save_checkpoint(
        tmp_path / "last",
        {"net": net},
        config={"k": 1},
        normalizer=norm,
        state={"step": 4},
        optimizer=_trained_optimizer(_net(0, width=64)).state_dict(),
    )
    out = C.export_weights(src, tmp_path / "ship")
    assert not (out / "trainer_state.pt").exists()
    assert json.loads((out / "format.json").read_text())["dtype"] == "float16"
    size = lambda p: (p / "net.safetensors").stat().st_size  # noqa: E731
    assert size(out) < 0.6 * size(src)
    back = _net(3, width=64)
    ck = C.load_checkpoint(out, {"net": back})
    assert ck.config == {"k": 1} and back[0].weight.dtype == torch.float32
    torch.testing.assert_close(ck.normalizer.std, norm.std, atol=0, rtol=0)
    for x, y in zip(net.state_dict().values(), back.state_dict().values(), strict=True):
        torch.testing.assert_close(y, x, atol=1e-3, rtol=1e-3)
    with pytest.raises(UMFError, match="cannot resume"):
        C.load_checkpoint(out, trainer_state=True)


def test_reserved_and_bad_module_names(tmp_path):
    for name in ("normalizer", "../x", ""):
        with pytest.raises(UMFError, match="invalid checkpoint module name"):
            C.save_checkpoint(tmp_path / "ck", {name: _net()})


def test_temporaries_of_a_killed_writer_are_removed(tmp_path):
    from umf.io import atomic_path, remove_stale_temporaries

    (tmp_path / ".loss_curves.png.abc123.tmp").write_bytes(b"")  # what kill -9 leaves
    (tmp_path / "keep.tmp").write_text("not ours")
    with atomic_path(tmp_path / "x.txt") as tmp:
        tmp.write_text("done")
    assert remove_stale_temporaries(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tmp", "x.txt"]


def test_a_figure_is_written_whole_or_not_at_all(tmp_path):
    """save_png_atomic: a PNG at the path, and a figure that fails to draw leaves the old
    picture and no temporary beside it."""
    from matplotlib.figure import Figure

    from umf.io import save_png_atomic

    fig = Figure(figsize=(2, 1))
    fig.subplots().plot([0, 1], [1, 0])
    out = save_png_atomic(fig, tmp_path / "a.png", dpi=50)
    first = out.read_bytes()
    assert out == tmp_path / "a.png" and first[:8] == b"\x89PNG\r\n\x1a\n"

    class Broken:
        def savefig(self, path, **kwargs):
            Path(path).write_bytes(b"half")
            raise RuntimeError("drawing failed")

    with pytest.raises(RuntimeError):
        save_png_atomic(Broken(), out)
    assert out.read_bytes() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]
