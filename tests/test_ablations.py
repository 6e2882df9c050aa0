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


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_ablation_trains_and_samples(name):
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
    if not cfg.vae.latent_adapter:
        assert r == cfg.vae.d_model
    pflow = PFlow(cfg.pflow, p, r, 16)
    sflow = SFlow(cfg.sflow, p, r, 16, backbone=pflow.net if cfg.sflow.shared_backbone else None)
    z = torch.randn(4, p, r)
    pl = pflow.loss(z, text(4), text(4, length=1), dataset=torch.tensor([0, 1, 1, 0]))
    pl["total"].backward()
    prev, prev_mask = torch.randn(4, 2, p, r), torch.tensor([[1, 0], [1, 1], [1, 1], [1, 0]]).bool()
    sl = sflow.loss(prev, prev_mask, z, text(4), text(4, length=1))
    sl["total"].backward()
    if cfg.sflow.reaction_only or cfg.sflow.lambda_recon == 0:
        total, reaction = float(sl["total"].detach()), float(sl["reaction"].detach())
        assert total == pytest.approx(reaction, rel=1e-6)
    gen = torch.Generator().manual_seed(0)
    z1, nfe1 = pflow.sample(text(2), text(2, length=1), generator=gen)
    w, nfe2 = sflow.sample(z1[:, None], torch.ones(2, 1, dtype=torch.bool), text(2),
                           text(2, length=1), generator=gen)  # fmt: skip
    assert z1.shape == w.shape == (2, p, r)
    per_step = 2 if "heun" in name else 1
    assert (
        nfe1 == sum(cfg.pflow.steps) * per_step
        if cfg.pflow.num_stages > 1 or name != "single_token"
        else True
    )
    assert nfe2 == cfg.sflow.steps * per_step
    assert torch.isfinite(z1).all() and torch.isfinite(w).all()


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
