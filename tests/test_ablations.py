"""Every ablation switch of the paper's tables builds, trains one step and samples."""

from __future__ import annotations

import pytest
import torch

from conftest import TINY_MODEL
from umf.config import set_option, small_config
from umf.models.pflow import PFlow
from umf.models.sflow import SFlow
from umf.models.vae import MotionVAE, vae_losses
from umf.representation import Normalizer
from umf.text import TextFeatures

TINY = [*TINY_MODEL, "vae.num_tokens=16", "vae.max_frames=40", "pflow.steps=[3,2]"]

ABLATIONS = {
    "full": [],
    "no_pyramid": ["pflow.num_stages=1"],
    "grid_pyramid": ["pflow.layout=2d"],
    "three_stages": ["pflow.num_stages=3", "pflow.steps=[2,2,2]"],
    "reaction_only": ["sflow.reaction_only=true"],
    "no_recon_loss": ["sflow.lambda_recon=0.0"],
    "no_context_adapter": ["sflow.context_adapter=false"],
    "shared_backbone": ["sflow.shared_backbone=true"],
    "single_token": ["vae.num_tokens=1", "pflow.num_stages=1"],
    "no_latent_adapter": ["vae.latent_adapter=false"],
    "heun": ["pflow.solver=heun", "sflow.solver=heun"],
    "unconditional_fine_stage": ["pflow.fine_guidance=0.0"],
    "early_fine_stage": ["pflow.starts=[0,0.25]"],
    "detail_norm": ["pflow.detail_norm=true"],
    "detail_norm_grid": ["pflow.detail_norm=true", "pflow.layout=2d"],
}


def text(b: int, dim: int = 16, length: int = 5) -> TextFeatures:
    g = torch.Generator().manual_seed(b)
    tokens = torch.randn(b, length, dim, generator=g)
    mask = torch.ones(b, length, dtype=torch.bool)
    return TextFeatures(tokens, mask, tokens.mean(1))


def _run(name: str) -> dict:
    """Build the ablation, take one loss of each model and sample once (fixed seeds)."""
    torch.manual_seed(0)
    cfg = small_config()
    for o in TINY + ABLATIONS[name]:
        cfg = set_option(cfg, o)
    vae = MotionVAE(cfg.vae)
    x, mask = torch.randn(3, 20, 262), torch.ones(3, 20, dtype=torch.bool)
    norm = Normalizer(torch.zeros(262), torch.ones(262))
    losses = vae_losses(vae(x, mask), x, mask, norm, cfg.vae)
    losses["total"].backward()
    p, r = vae.latent_shape
    pflow = PFlow(cfg.pflow, p, r, 16)
    sflow = SFlow(cfg.sflow, p, r, 16, backbone=pflow.net if cfg.sflow.shared_backbone else None)
    z = torch.randn(4, p, r)
    pl = pflow.loss(z, text(4), text(4, length=1), dataset=torch.tensor([0, 1, 1, 0]))
    pl["total"].backward()
    prev, prev_mask = torch.randn(4, 2, p, r), torch.tensor([[1, 0], [1, 1], [1, 1], [1, 0]]).bool()
    sl = sflow.loss(prev, prev_mask, z, text(4), text(4, length=1))
    sl["total"].backward()
    gen = torch.Generator().manual_seed(0)
    z1, nfe1 = pflow.sample(text(2), text(2, length=1), generator=gen)
    w, nfe2 = sflow.sample(z1[:, None], torch.ones(2, 1, dtype=torch.bool), text(2),
                           text(2, length=1), generator=gen)  # fmt: skip
    params = sum(m.numel() for m in [*pflow.parameters(), *sflow.parameters()])
    return {"cfg": cfg, "vae": vae, "vae_loss": float(losses["total"].detach()),
            "latent": (p, r), "pflow_loss": float(pl["total"].detach()), "sflow": sl,
            "z1": z1, "w": w, "nfe": (nfe1, nfe2), "params": params}  # fmt: skip


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_ablation_trains_and_samples(name):
    out = _run(name)
    cfg, (p, r), (nfe1, nfe2) = out["cfg"], out["latent"], out["nfe"]
    if not cfg.vae.latent_adapter:
        assert r == cfg.vae.d_model
    sl = out["sflow"]
    if cfg.sflow.reaction_only or cfg.sflow.lambda_recon == 0:
        total, reaction = float(sl["total"].detach()), float(sl["reaction"].detach())
        assert total == pytest.approx(reaction, rel=1e-6)
    assert out["z1"].shape == out["w"].shape == (2, p, r)
    per_step = 2 if "heun" in name else 1
    steps = cfg.pflow.steps if len(cfg.pflow.steps) == cfg.pflow.num_stages else (
        sum(cfg.pflow.steps),)  # one stage given two counts integrates their sum  # fmt: skip
    assert nfe1 == sum(steps) * per_step, (nfe1, cfg.pflow.steps)
    assert nfe2 == cfg.sflow.steps * per_step
    assert torch.isfinite(out["z1"]).all() and torch.isfinite(out["w"]).all()


def _differences(a: dict, b: dict) -> list[str]:
    keys = ["vae_loss", "latent", "pflow_loss", "nfe", "params"]
    out = [k for k in keys if a[k] != b[k]]
    out += [k for k in ("z1", "w") if a[k].shape != b[k].shape or not torch.equal(a[k], b[k])]
    if float(a["sflow"]["total"].detach()) != float(b["sflow"]["total"].detach()):
        out.append("sflow_loss")
    return out


# What each switch must change against the full model under the same seeds: its own part
# (the first-person sample z1 comes from a fixed generator, so it moves only when the
# P-Flow or its sampling does; sflow_loss only when the S-Flow objective does).
EFFECTS = {
    "no_pyramid": {"z1"}, "grid_pyramid": {"z1"}, "three_stages": {"nfe", "z1"},
    "reaction_only": {"sflow_loss", "w"}, "no_recon_loss": {"sflow_loss"},
    "no_context_adapter": {"params", "w"}, "shared_backbone": {"params", "w"},
    "single_token": {"latent"}, "no_latent_adapter": {"latent"}, "heun": {"nfe", "z1"},
    "unconditional_fine_stage": {"z1"}, "early_fine_stage": {"z1"}, "detail_norm": {"z1"},
    "detail_norm_grid": {"z1"},
}  # fmt: skip


def test_each_ablation_switch_changes_the_model():
    """Same seeds, one switch flipped: what the switch is about changes (a switch the code
    ignored would leave every loss and sample of the full model as they were)."""
    assert set(EFFECTS) == set(ABLATIONS) - {"full"}
    full = _run("full")
    changed = {name: set(_differences(_run(name), full)) for name in EFFECTS}
    missing = {k: sorted(EFFECTS[k] - v) for k, v in changed.items() if not EFFECTS[k] <= v}
    assert not missing, missing
    assert not {"z1", "pflow_loss"} & changed["no_recon_loss"]  # an S-Flow switch only


def test_shared_backbone_model_loads_the_fine_tuned_transformer_for_both_flows(tmp_path):
    """S-Flow training fine-tunes the shared transformer, so a loaded model must run P-Flow
    with S-Flow's copy of it (the P-Flow checkpoint still holds the pre-S-Flow weights)."""
    from umf.checkpoint import save_checkpoint
    from umf.pipeline import UMFPipeline

    cfg = small_config()
    for o in (*TINY_MODEL, "sflow.shared_backbone=true"):
        cfg = set_option(cfg, o)
    torch.manual_seed(0)
    pipe = UMFPipeline.build(cfg)
    pflow_state = {k: v.clone() for k, v in pipe.pflow.state_dict().items()}
    with torch.no_grad():  # "fine-tune" the shared transformer
        for p in pipe.sflow.net.parameters():
            p.add_(0.5)
    modules = {"vae": pipe.vae, "pflow": pflow_state, "sflow": pipe.sflow}
    save_checkpoint(tmp_path / "m", modules, config=cfg.to_dict(), normalizer=pipe.normalizer)
    loaded = UMFPipeline.from_pretrained(tmp_path / "m")
    assert loaded.pflow.net is loaded.sflow.net
    for k, v in pipe.sflow.net.state_dict().items():
        torch.testing.assert_close(loaded.pflow.net.state_dict()[k], v)
    k = next(k for k in pflow_state if k.startswith("net."))  # the stale copy in the P-Flow file
    assert not torch.equal(loaded.pflow.state_dict()[k], pflow_state[k])
    scene = loaded("two people bow", num_people=2, seconds=1.0, seed=0)[0]
    assert torch.isfinite(torch.as_tensor(scene.joints)).all()
