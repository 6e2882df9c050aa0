"""The motion VAE: shapes, masking, ablations, losses, gradients and a real overfit."""

from __future__ import annotations

import dataclasses
import time

import pytest
import torch

from umf.body_frame import fit_body_normalizer
from umf.config import VAEConfig
from umf.models.vae import (
    MotionVAE,
    VAEOutput,
    count_parameters,
    interaction_loss,
    kl_loss,
    reconstruction_loss,
    root_velocity_loss,
    vae_losses,
)
from umf.representation import Normalizer, features_to_joints, joints_to_features

TINY = VAEConfig(
    d_model=32, num_layers=3, num_heads=4, ff_dim=64, dropout=0.0,
    num_tokens=4, latent_dim=8, max_frames=32,
    # the geometric terms are off by default; these tests check them
    w_pos=0.5, w_vel=0.5, w_contact=0.1, w_bone=0.1, w_interaction=0.5,
)  # fmt: skip
GEOMETRIC = ("pos", "vel", "contact", "bone")
# overfit limits (m), measured 0.038 pose (root-relative) and 0.21 global with seed 0
POSE_LIMIT, GLOBAL_LIMIT = 0.06, 0.30


def tiny(**overrides) -> MotionVAE:
    torch.manual_seed(0)
    return MotionVAE(dataclasses.replace(TINY, **overrides))


def lengths_mask(lengths: list[int], t: int) -> torch.Tensor:
    return torch.arange(t)[None] < torch.tensor(lengths)[:, None]


@pytest.fixture(scope="module")
def walk_features(real_joints) -> torch.Tensor:
    """Raw features (40, 262) of a real walk: has planted feet, so contacts are 1 somewhere."""
    return joints_to_features(real_joints[:41].float())


# --------------------------------------------------------------------- model
def test_shapes_for_variable_lengths():
    model = tiny().eval()
    mask = lengths_mask([24, 10, 17], 24)
    out = model(torch.randn(3, 24, 262), mask)
    assert out.x_hat.shape == (3, 24, 262)
    for t in (out.mu, out.logvar, out.z):
        assert t.shape == (3, 4, 8)
    assert model.latent_shape == (4, 8)
    assert model.decode(out.z, lengths_mask([5, 7, 3], 7)).shape == (3, 7, 262)


@pytest.mark.parametrize("grad", [False, True])
def test_padded_frames_do_not_leak(grad):
    """Exact: padding changes neither the latent nor the valid output frames."""
    model = tiny().eval()
    mask = lengths_mask([24, 10, 17], 24)
    x = torch.randn(3, 24, 262)
    x2 = x.clone()
    x2[~mask] = torch.randn(int((~mask).sum()), 262) * 100.0
    x2[1, -1] = float("nan")
    with torch.set_grad_enabled(grad):
        a, b = model(x, mask, sample=False), model(x2, mask, sample=False)
    assert torch.equal(a.mu, b.mu) and torch.equal(a.logvar, b.logvar)
    assert torch.equal(a.x_hat[mask], b.x_hat[mask])


def test_ablations_and_errors():
    no_adapter = tiny(latent_adapter=False)
    assert no_adapter.latent_shape == (4, 32)
    mu, logvar = no_adapter.encode(torch.randn(2, 10, 262), lengths_mask([10, 6], 10))
    assert mu.shape == logvar.shape == (2, 4, 32)
    assert count_parameters(no_adapter) < count_parameters(tiny())

    single = tiny(num_tokens=1)
    out = single(torch.randn(2, 10, 262), lengths_mask([10, 6], 10))
    assert out.z.shape == (2, 1, 8) and out.x_hat.shape == (2, 10, 262)

    model = tiny()
    with pytest.raises(ValueError, match="max_frames"):
        model.encode(torch.randn(1, 33, 262), torch.ones(1, 33, dtype=torch.bool))
    with pytest.raises(ValueError, match="max_frames"):
        model.decode(torch.randn(1, 4, 8), torch.ones(1, 33, dtype=torch.bool))
    with pytest.raises(ValueError, match="valid frame"):
        model.encode(torch.randn(2, 5, 262), lengths_mask([5, 0], 5))
    with pytest.raises(ValueError, match="expected z"):
        model.decode(torch.randn(1, 4, 9), torch.ones(1, 5, dtype=torch.bool))


def test_count_parameters():
    model = tiny()
    assert count_parameters(model) == sum(p.numel() for p in model.parameters())
    model.out_proj.requires_grad_(False)
    frozen = model.out_proj.weight.numel() + model.out_proj.bias.numel()
    assert count_parameters(model, trainable_only=True) == count_parameters(model) - frozen


def test_deterministic_under_seed():
    x, mask = torch.randn(2, 12, 262), lengths_mask([12, 8], 12)
    outs = []
    for _ in range(2):
        model = tiny(dropout=0.1).train()  # seeds itself; dropout active
        torch.manual_seed(1)
        outs.append(model(x, mask, generator=torch.Generator().manual_seed(3)))
    assert torch.equal(outs[0].x_hat, outs[1].x_hat) and torch.equal(outs[0].z, outs[1].z)
    model = tiny().eval()
    det = model(x, mask, sample=False)
    assert torch.equal(det.z, det.mu)


@pytest.mark.parametrize("overrides", [{}, {"latent_adapter": False}, {"num_tokens": 1}])
def test_gradients_reach_every_parameter(overrides, walk_features):
    """No unused parameters: DDP without find_unused_parameters must work."""
    model = tiny(dropout=0.1, **overrides).train()
    feats = torch.stack([walk_features[:20], walk_features[20:]])
    norm = Normalizer.fit(feats)
    x, mask = norm.normalize(feats), lengths_mask([20, 14], 20)
    out = model(x, mask)
    vae_losses(out, x, mask, norm, model.cfg, people=torch.tensor([[0, 1]]))["total"].backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name  # in the graph: what DDP needs
        if model.cfg.num_tokens == 1 and name.startswith("decoder.") and ".norm2." in name:
            continue  # softmax over a single memory token is 1: the cross-attn query is inert
        assert p.grad.abs().sum() > 0, name


# --------------------------------------------------------------------- losses
def test_kl_matches_closed_form():
    mu = torch.tensor([[[0.0, 1.0], [-2.0, 0.5]]])
    logvar = torch.tensor([[[0.0, 0.0], [1.0, -1.0]]])
    # per element 0.5 * (sigma^2 + mu^2 - 1 - log sigma^2), worked by hand
    e = torch.e
    by_hand = (0.0 + 0.5 + 0.5 * (e + 4 - 1 - 1) + 0.5 * (1 / e + 0.25 - 1 + 1)) / 4
    assert kl_loss(mu, logvar).item() == pytest.approx(by_hand, rel=1e-6)
    dist = torch.distributions
    ref = dist.kl_divergence(dist.Normal(mu, (0.5 * logvar).exp()), dist.Normal(0.0, 1.0))
    assert torch.allclose(kl_loss(mu, logvar), ref.mean())
    assert kl_loss(torch.zeros(2, 3, 4), torch.zeros(2, 3, 4)).item() == 0.0


def test_recon_zero_for_perfect_prediction_and_masked():
    x = torch.randn(2, 6, 262)
    mask = lengths_mask([6, 3], 6)
    assert reconstruction_loss(x, x, mask).item() == 0.0
    garbage = x.clone()
    garbage[~mask] += 5.0  # errors on padded frames are ignored
    assert reconstruction_loss(garbage, x, mask).item() == 0.0
    assert reconstruction_loss(x + 0.1, x, mask).item() > 0.0


def _output(x_hat: torch.Tensor) -> VAEOutput:
    z = torch.zeros(x_hat.shape[0], 4, 8)
    return VAEOutput(x_hat=x_hat, mu=z, logvar=z, z=z)


def test_geometric_terms_zero_at_truth_positive_otherwise(walk_features):
    feats = walk_features[None]
    assert feats[..., 258:].sum() > 0  # the walk plants its feet
    norm = Normalizer.fit(feats)
    x, mask = norm.normalize(feats), torch.ones(1, 40, dtype=torch.bool)
    exact = vae_losses(_output(x.clone()), x, mask, norm, TINY)
    for k in (*GEOMETRIC, "recon"):  # vel compares position differences with velocity slots
        assert exact[k].item() == pytest.approx(0.0, abs=1e-6 if k == "vel" else 0.0), k
    torch.manual_seed(0)
    noisy = vae_losses(_output(x + 0.3 * torch.randn_like(x)), x, mask, norm, TINY)
    for k in (*GEOMETRIC, "recon"):
        assert noisy[k].item() > 0.0, k
    assert "interaction" not in noisy  # single people: no scene structure given


def test_zero_weight_removes_term(walk_features):
    feats = walk_features[None]
    norm = Normalizer.fit(feats)
    x, mask = norm.normalize(feats), torch.ones(1, 40, dtype=torch.bool)
    out = _output(x + 0.1)
    out.mu = torch.ones(1, 4, 8)
    full = vae_losses(out, x, mask, norm, TINY)
    cfg = dataclasses.replace(TINY, w_bone=0.0, w_kl=0.0)
    part = vae_losses(out, x, mask, norm, cfg)
    assert "bone" not in part and "kl" not in part
    weights = {"recon": 1.0, "kl": 1e-4, "pos": 0.5, "vel": 0.5, "contact": 0.1, "bone": 0.1}
    assert torch.allclose(full["total"], sum(weights[k] * full[k] for k in weights))
    expected = full["total"] - 0.1 * full["bone"] - 1e-4 * full["kl"]
    assert torch.allclose(part["total"], expected)
    geo_off = dataclasses.replace(TINY, w_pos=0, w_vel=0, w_contact=0, w_bone=0)
    assert set(vae_losses(out, x, mask, norm, geo_off)) == {"recon", "kl", "total"}


def test_interaction_term(real_joints):
    """Two real people 0.6 m apart: exact -> 0, a shifted person -> > 0."""
    a = real_joints[:31].float()
    b = a + torch.tensor([0.6, 0.0, 0.0])
    feats = torch.stack([joints_to_features(a), joints_to_features(b)])
    norm = Normalizer.fit(feats)
    x, mask = norm.normalize(feats), torch.ones(2, 30, dtype=torch.bool)
    people = torch.tensor([[0, 1]])
    exact = vae_losses(_output(x.clone()), x, mask, norm, TINY, people=people)
    assert exact["interaction"].item() == 0.0
    shifted = feats.clone()
    shifted[1, :, :66] += torch.tensor([0.2, 0.0, 0.0]).repeat(22)
    moved = vae_losses(_output(norm.normalize(shifted)), x, mask, norm, TINY, people=people)
    assert moved["interaction"].item() > 0.1  # about the 0.2 m shift
    # a scene of one person (slot -1) has no pair
    lonely = vae_losses(_output(x), x, mask, norm, TINY, people=torch.tensor([[0, -1]]))
    assert lonely["interaction"].item() == 0.0

    # direct form: moving the whole scene rigidly keeps every distance map
    joints = torch.stack([a, b])[None]  # (S=1, P=2, T, 22, 3)
    m = torch.ones(1, 31, dtype=torch.bool)
    assert interaction_loss(joints + 1.0, joints, m).item() == pytest.approx(0.0, abs=1e-5)
    far = torch.stack([a, a + torch.tensor([5.0, 0.0, 0.0])])[None]
    assert interaction_loss(far, far + 0.01, m).item() == 0.0  # rigid, far apart
    pred_far = far.clone()
    pred_far[:, 1, :, :, 0] -= 4.8  # prediction brings them falsely close
    assert interaction_loss(pred_far, far, m).item() > 1.0


# --------------------------------------------------------------------- training
def test_overfits_real_clips(bandai_clips):
    """150 Adam steps on 4 real Bandai clips (48 frames): total loss down >= 5x, the pose
    (root-relative joints) within 6 cm, the placement within 30 cm."""
    ids = (
        "dataset-1_bow_normal_001", "dataset-1_kick_normal_001",
        "dataset-1_walk_normal_001", "dataset-2_run_normal_001",
    )  # fmt: skip
    clips = {c.id: c for c in bandai_clips}
    feats = torch.stack(
        [joints_to_features(torch.from_numpy(clips[i].joints[0]))[:48] for i in ids]
    )
    norm = Normalizer.fit(feats)
    x, mask = norm.normalize(feats), torch.ones(4, 48, dtype=torch.bool)
    cfg = VAEConfig(
        d_model=128, num_layers=3, num_heads=4, ff_dim=256, dropout=0.0,
        num_tokens=4, latent_dim=8, max_frames=64,
    )  # fmt: skip
    torch.manual_seed(0)
    model = MotionVAE(cfg)
    model.set_normalizers(norm, fit_body_normalizer(feats))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / 15))
    gen = torch.Generator().manual_seed(0)
    start = time.perf_counter()
    for step in range(150):
        losses = vae_losses(model(x, mask, generator=gen), x, mask, norm, cfg)
        if step == 0:
            first = losses["total"].item()
        opt.zero_grad()
        losses["total"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
    model.eval()
    with torch.no_grad():
        out = model(x, mask, sample=False)
        last = vae_losses(out, x, mask, norm, cfg)["total"].item()
        pred = features_to_joints(norm.denormalize(out.x_hat))
        true = features_to_joints(feats)
        err = (pred - true).norm(dim=-1).mean().item()
        pose = ((pred - pred[..., :1, :]) - (true - true[..., :1, :])).norm(dim=-1).mean().item()
    print(f"overfit: total {first:.3f} -> {last:.3f} ({first / last:.1f}x), "
          f"mean joint error {err:.3f} m, pose {pose:.3f} m, "
          f"{time.perf_counter() - start:.1f} s")  # fmt: skip
    assert first / last >= 5.0
    assert pose < POSE_LIMIT and err < GLOBAL_LIMIT


def test_root_velocity_loss_measures_drift_in_m_per_s(walk_features):
    """0 at the truth; a pelvis velocity slot off by 0.1 m/s sideways (at 30 fps) costs
    0.1, whatever the rest of the body does; padded frames do not count."""
    feats = walk_features[None]
    mask = torch.ones(1, 40, dtype=torch.bool)
    assert root_velocity_loss(feats, feats, mask, 30.0).item() == 0.0
    drift = feats.clone()
    drift[..., 66] += 0.1 / 30  # the pelvis's x velocity slot
    drift[..., 69:132] += 1.0  # other joints' velocities: not this term's business
    assert root_velocity_loss(drift, feats, mask, 30.0).item() == pytest.approx(0.1, rel=1e-4)
    half = mask.clone()
    half[:, 20:] = False
    drift[:, 20:, 66] += 5.0
    assert root_velocity_loss(drift, feats, half, 30.0).item() == pytest.approx(0.1, rel=1e-4)
    norm = Normalizer.fit(feats)
    x = norm.normalize(feats)
    cfg = dataclasses.replace(TINY, w_root_vel=2.0)
    terms = vae_losses(_output(norm.normalize(drift)), x, half, norm, cfg, fps=30.0)
    assert terms["root_vel"].item() == pytest.approx(0.1, rel=1e-3)
    assert "root_vel" not in vae_losses(_output(x), x, mask, norm, TINY)


def test_freeze_encoder_leaves_latents_fixed(walk_features):
    """A decoder-only step changes the decoder and not one encoder weight (the latents the
    flows were trained on stay exactly the same)."""
    vae = tiny()
    vae.freeze_encoder()
    x = walk_features[None, :32] / 10
    mask = torch.ones(1, 32, dtype=torch.bool)
    before = {k: v.clone() for k, v in vae.state_dict().items()}
    mu_before = vae.encode(x, mask)[0]
    opt = torch.optim.SGD([p for p in vae.parameters() if p.requires_grad], lr=0.1)
    out = vae(x, mask)
    reconstruction_loss(out.x_hat, x, mask).backward()
    opt.step()
    after = vae.state_dict()
    enc = ("in_proj", "encoder.", "adapter", "query_tokens")
    assert all(torch.equal(before[k], after[k]) for k in before if k.startswith(enc))
    assert any(not torch.equal(before[k], after[k]) for k in before if k.startswith("decoder."))
    assert torch.equal(vae.encode(x, mask)[0], mu_before)


def test_fusion_weights_are_checked_and_old_configs_keep_their_decoding():
    """A fusion weight of 0 leaves the floor path undetermined (a singular system): refused
    by name. A config saved before height_fusion / reaction_root_fusion existed decodes
    everything at its own root_fusion, not at the new defaults."""
    from umf.config import UMFConfig, set_option, small_config
    from umf.errors import UMFError
    from umf.model_checks import check_config_values

    cfg = small_config()
    for bad in ("vae.root_fusion=0", "vae.reaction_root_fusion=0", "vae.height_fusion=-1",
                "vae.position_fusion=-0.5"):  # fmt: skip
        with pytest.raises(UMFError, match=bad.split("=")[0]):
            check_config_values(set_option(cfg, bad))
    check_config_values(set_option(cfg, "vae.reaction_root_fusion=null"))
    old = cfg.to_dict()
    for key in ("height_fusion", "reaction_root_fusion"):
        del old["vae"][key]
    old["vae"]["root_fusion"] = 0.005
    legacy = UMFConfig.from_dict(old).vae
    assert (legacy.root_fusion, legacy.height_fusion, legacy.reaction_root_fusion) == (
        0.005, None, None)  # fmt: skip
    fresh = UMFConfig.from_dict(cfg.to_dict()).vae
    assert (fresh.height_fusion, fresh.reaction_root_fusion) == (1.0, 0.001)
