"""The S-Flow's loss on the decoded reaction's feet (``train_sflow.foot_loss``): the
reaction the prediction points at, the hinge on feet sliding where the real ones are planted,
and its place in a training step."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from umf.flows import reaction_endpoint, semi_noise_state
from umf.representation import FEATURE_DIM, Normalizer
from umf.train.foot_slide import decoded_foot_slide

pytestmark = pytest.mark.usefixtures("one_thread")


def test_the_endpoint_of_the_target_velocity_is_the_reaction():
    g = torch.Generator().manual_seed(0)
    c, w, eps = (torch.randn(5, 4, 6, generator=g) for _ in range(3))
    t = torch.rand(5, generator=g)
    for only in (False, True):
        s = semi_noise_state(c, w, eps, t, reaction_only=only)
        assert torch.allclose(reaction_endpoint(s.x, s.target, t, reaction_only=only), w,
                              atol=1e-6)  # fmt: skip
    s = semi_noise_state(c, w, eps, t)
    off = reaction_endpoint(s.x, s.target + 1.0, t)  # a velocity 1 too fast everywhere
    assert torch.allclose(off - w, (1 - t)[:, None, None].expand_as(w), atol=1e-6)


class GlidingDecoder(nn.Module):
    """Every joint on the floor, travelling along x at z[:, 0, 0] metres per frame."""

    def decode(self, z: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        b, t = mask.shape
        x = z[:, 0, 0, None] * torch.arange(t, dtype=z.dtype)  # (B, T)
        pos = torch.zeros(b, t, 22, 3, dtype=z.dtype)
        pos = pos + torch.stack([x, torch.zeros_like(x), torch.zeros_like(x)], -1)[:, :, None]
        return torch.cat([pos.flatten(2), torch.zeros(b, t, FEATURE_DIM - 66)], dim=-1)


IDENTITY = Normalizer(torch.zeros(FEATURE_DIM), torch.ones(FEATURE_DIM))


def test_sliding_planted_feet_costs_their_excess_speed_and_only_late_in_the_flow():
    vae = GlidingDecoder()
    w = torch.zeros(4, 2, 3)  # real reactions stand: every foot planted
    w_hat = torch.zeros(4, 2, 3)
    w_hat[:, 0, 0] = torch.tensor([0.05, 0.05, 0.02, 0.02])
    w_hat.requires_grad_(True)
    late = torch.ones(4)
    slide = decoded_foot_slide(vae, IDENTITY, w, w_hat, late, frames=10)
    assert float(slide.detach()) == pytest.approx(0.035, abs=1e-5)  # the mean excess, m/frame
    slide.backward()
    assert float(w_hat.grad[:, 0, 0].abs().min()) > 0
    w_hat = w_hat.detach()
    assert float(decoded_foot_slide(vae, IDENTITY, w, w.clone(), late, frames=10)) == 0.0
    early = torch.tensor([0.1, 0.2, 0.9, 0.9])  # only the last two rows count
    assert float(decoded_foot_slide(vae, IDENTITY, w, w_hat, early, frames=10)) == \
        pytest.approx(0.02, abs=1e-5)  # fmt: skip
    assert float(decoded_foot_slide(vae, IDENTITY, w, w_hat, torch.zeros(4), frames=10)) == 0.0
    moving = torch.zeros(4, 2, 3)
    moving[:, 0, 0] = 0.05  # real reactions that travel: no foot planted, nothing to keep
    assert float(decoded_foot_slide(vae, IDENTITY, moving, w_hat, late, frames=10)) == 0.0


def test_at_most_rows_are_decoded():
    vae = GlidingDecoder()
    w, w_hat = torch.zeros(4, 2, 3), torch.zeros(4, 2, 3)
    w_hat[:, 0, 0] = torch.tensor([0.05, 0.01, 0.01, 0.01])
    late = torch.ones(4)
    assert float(decoded_foot_slide(vae, IDENTITY, w, w_hat, late, rows=1, frames=10)) == \
        pytest.approx(0.05, abs=1e-5)  # fmt: skip
    assert float(decoded_foot_slide(vae, IDENTITY, w, w_hat, late, rows=4, frames=10)) == \
        pytest.approx(0.02, abs=1e-5)  # fmt: skip


def test_a_training_step_adds_the_weighted_foot_loss_and_trains_only_the_flow():
    from conftest import FakeText, tiny_config
    from umf.pipeline import UMFPipeline
    from umf.text import TextFeatureCache
    from umf.train.stages import SFlowStage

    torch.manual_seed(0)
    pipe = UMFPipeline.build(tiny_config(), text_encoder=FakeText())
    p, r = pipe.vae.latent_shape
    batch = {"z": torch.randn(6, 2, p, r), "people_mask": torch.ones(6, 2, dtype=torch.bool),
             "dataset": torch.ones(6, dtype=torch.long), "captions": ["a"] * 6}  # fmt: skip
    cache = TextFeatureCache(FakeText())
    # a normaliser of centimetre-sized spreads: the random tiny VAE's feet then move slowly
    # enough for some to count as planted
    tiny = Normalizer(torch.zeros(FEATURE_DIM), torch.full((FEATURE_DIM,), 0.01))

    def stage(weight: float) -> SFlowStage:
        pipe.config.train_sflow.foot_loss, pipe.config.train_sflow.foot_loss_min_t = weight, 0.0
        return SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow, seed=3, normalizer=tiny)

    plain, on = stage(0.0).training_step(batch, 0), stage(2.0)
    feet = on.training_step(batch, 0)
    assert "foot" not in plain and "endpoint" not in feet and "t" not in feet
    assert float(feet["foot"]) > 0
    want = float(plain["total"]) + 2.0 * float(feet["foot"])
    assert float(feet["total"].detach()) == pytest.approx(want, rel=1e-5)
    pipe.sflow.zero_grad()
    (feet["total"] - plain["total"].detach()).backward()  # the foot term's gradient alone
    grads = [q.grad for q in pipe.sflow.net.parameters() if q.grad is not None]
    assert grads and sum(float(g.abs().sum()) for g in grads) > 0
    assert all(q.grad is None for q in pipe.vae.parameters())
    assert on.validation_step(batch)["foot"] > 0
    pipe.config.train_sflow.foot_loss = 1.0
    with pytest.raises(ValueError, match="normaliser"):
        SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow)


def test_the_options_are_checked():
    from umf.config import set_option, small_config
    from umf.errors import UMFError
    from umf.model_checks import check_config_values

    check_config_values(set_option(small_config(), "train_sflow.foot_loss=4.0"))
    for bad, says in (("train_pflow.foot_loss=1.0", "only train_sflow"),
                      ("train_sflow.foot_loss=-1.0", "foot_loss"),
                      ("train_sflow.foot_loss_min_t=1.5", "foot_loss_min_t"),
                      ("sflow.p_scene_drop=2.0", "p_scene_drop"),
                      ("sflow.denoiser.person_head=true", "needs sflow.denoiser.person_text"),
                      ):  # fmt: skip
        with pytest.raises(UMFError, match=says):
            check_config_values(set_option(small_config(), bad))
