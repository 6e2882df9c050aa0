"""The S-Flow's loss on where the decoded reaction stands (``train_sflow.place_loss``):
metres between pelvis floor paths, early flow times only, and its place in a training step."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from umf.representation import FEATURE_DIM, Normalizer
from umf.train.placement import decoded_place_errors

pytestmark = pytest.mark.usefixtures("one_thread")

IDENTITY = Normalizer(torch.zeros(FEATURE_DIM), torch.ones(FEATURE_DIM))


def decoded_place_error(*args, **kwargs) -> torch.Tensor:
    return decoded_place_errors(*args, **kwargs)["place"]


class StandingDecoder(nn.Module):
    """Every joint at floor position (z[:, 0, 0], z[:, 0, 1]) metres, still; the joints after
    the pelvis (z[:, 1, 0]) metres up from it."""

    def decode(self, z: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        b, t = mask.shape
        at = torch.stack([z[:, 0, 0], torch.zeros_like(z[:, 0, 0]), z[:, 0, 1]], -1)
        up = torch.zeros(b, 22, 3)
        up[:, 1:, 1] = z[:, 1, 0:1]
        pos = (at[:, None, None] + up[:, None]).expand(b, t, 22, 3)
        return torch.cat([pos.flatten(2), torch.zeros(b, t, FEATURE_DIM - 66)], dim=-1)


def test_the_error_is_the_floor_distance_and_only_early_in_the_flow():
    vae = StandingDecoder()
    w = torch.zeros(4, 2, 3)
    w[:, 0, 0] = 0.9  # real partners 0.9 m to the left
    w_hat = torch.zeros(4, 2, 3)
    w_hat[:, 0, 0] = torch.tensor([-0.9, 0.0, 0.9, 0.9])  # wrong side, on person 1, right
    w_hat[:, 0, 1] = torch.tensor([0.0, 0.0, 0.0, 0.4])  # the last one 0.4 m ahead too
    w_hat.requires_grad_(True)
    early = torch.zeros(4)
    err = decoded_place_error(vae, IDENTITY, w, w_hat, early, frames=5)
    assert float(err.detach()) == pytest.approx((1.8 + 0.9 + 0.0 + 0.4) / 4, abs=1e-5)
    err.backward()
    assert float(w_hat.grad[0, 0, 0]) < 0 < float(w_hat.grad[3, 0, 1])  # towards the real
    w_hat = w_hat.detach()
    assert float(decoded_place_error(vae, IDENTITY, w, w.clone(), early, frames=5)) == 0.0
    t = torch.tensor([0.1, 0.9, 0.9, 0.9])  # only the first row counts at max_t 0.5
    assert float(decoded_place_error(vae, IDENTITY, w, w_hat, t, frames=5)) == \
        pytest.approx(1.8, abs=1e-5)  # fmt: skip
    assert float(decoded_place_error(vae, IDENTITY, w, w_hat, torch.ones(4), frames=5)) == 0.0
    assert float(decoded_place_error(vae, IDENTITY, w, w_hat, early, rows=2, frames=5)) == \
        pytest.approx(1.35, abs=1e-5)  # fmt: skip


def test_the_joint_error_reads_every_joint_in_3d_from_the_same_rows():
    vae = StandingDecoder()
    w = torch.zeros(3, 2, 3)
    w_hat = torch.zeros(3, 2, 3)
    w_hat[0, 0, 0] = 0.6  # 0.6 m aside: every joint
    w_hat[1, 1, 0] = 0.44  # the pelvis in place, the 21 other joints 0.44 m too high
    w_hat[2, 0, 0], w_hat[2, 1, 0] = 0.3, 0.4  # both: 0.3 m for the pelvis, 0.5 m for the rest
    w_hat.requires_grad_(True)
    got = decoded_place_errors(vae, IDENTITY, w, w_hat, torch.zeros(3), frames=4)
    assert float(got["place"].detach()) == pytest.approx((0.6 + 0.0 + 0.3) / 3, abs=1e-5)
    want = (0.6 + 0.44 * 21 / 22 + (0.3 + 0.5 * 21) / 22) / 3
    assert float(got["joint"].detach()) == pytest.approx(want, abs=1e-5)
    got["joint"].backward()
    assert float(w_hat.grad[1, 1, 0]) > 0  # lower the raised joints
    late = decoded_place_errors(vae, IDENTITY, w, w_hat.detach(), torch.ones(3), frames=4)
    assert float(late["joint"]) == 0.0 == float(late["place"])


def test_a_training_step_adds_the_weighted_place_loss():
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

    def stage(weight: float) -> SFlowStage:
        pipe.config.train_sflow.place_loss, pipe.config.train_sflow.place_loss_max_t = weight, 1.0
        return SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow, seed=3, normalizer=IDENTITY)

    plain, on = stage(0.0).training_step(batch, 0), stage(2.0)
    placed = on.training_step(batch, 0)
    assert "place" not in plain and "foot" not in placed and "endpoint" not in placed
    assert float(placed["place"]) > 0
    want = float(plain["total"]) + 2.0 * float(placed["place"])
    assert float(placed["total"].detach()) == pytest.approx(want, rel=1e-5)
    pipe.sflow.zero_grad()
    (placed["total"] - plain["total"].detach()).backward()
    assert any(q.grad is not None and float(q.grad.abs().sum()) > 0
               for q in pipe.sflow.net.parameters())  # fmt: skip
    assert all(q.grad is None for q in pipe.vae.parameters())
    assert on.validation_step(batch)["place"] > 0
    pipe.config.train_sflow.place_loss, pipe.config.train_sflow.joint_loss = 0.0, 0.5
    jointed = SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow, seed=3, normalizer=IDENTITY)
    both = jointed.training_step(batch, 0)
    assert "place" not in both and float(both["joint"]) > 0
    want = float(plain["total"]) + 0.5 * float(both["joint"])
    assert float(both["total"].detach()) == pytest.approx(want, rel=1e-5)
    pipe.config.train_sflow.joint_loss = 0.0
    pipe.config.train_sflow.place_loss = 1.0
    with pytest.raises(ValueError, match="normaliser"):
        SFlowStage(pipe.config, pipe.vae, cache, pipe.sflow)


def test_the_options_are_checked():
    from umf.config import set_option, small_config
    from umf.errors import UMFError
    from umf.model_checks import check_config_values

    check_config_values(set_option(small_config(), "train_sflow.place_loss=0.3"))
    check_config_values(set_option(small_config(), "train_sflow.joint_loss=0.1"))
    for bad, says in (("train_pflow.place_loss=1.0", "only train_sflow"),
                      ("train_vae.joint_loss=0.1", "only train_sflow"),
                      ("train_sflow.joint_loss=-0.1", "joint_loss"),
                      ("train_sflow.place_loss=-1.0", "place_loss"),
                      ("train_sflow.place_loss_max_t=1.5", "place_loss_max_t")):  # fmt: skip
        with pytest.raises(UMFError, match=says):
            check_config_values(set_option(small_config(), bad))
