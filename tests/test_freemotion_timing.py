"""The FreeMotion-class timing baseline and the FLOP counter the speed benchmark uses:
the counts match the formulas, DDIM lands on the network's clean estimate, and the
ControlNet branch is wired but silent at initialisation, as ControlNet's zero convs are."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from umf.eval.flops import count_flops
from umf.eval.freemotion import (
    FreeMotionConfig,
    FreeMotionNet,
    ddim_alphas,
    sample_person,
    sample_scene,
)

SMALL = FreeMotionConfig(feature_dim=12, dim=32, num_layers=2, num_heads=4, ff_dim=64,
                         text_dim=16, steps=10)  # fmt: skip


def test_flops_of_a_linear_and_of_a_transformer_layer_match_their_formulas():
    lin = nn.Linear(30, 20)
    assert count_flops(lambda: lin(torch.randn(7, 30))) == 2 * 7 * 30 * 20
    b, t, d, ff = 2, 50, 64, 128
    layer = nn.TransformerEncoderLayer(d, 4, ff, 0.0, batch_first=True, norm_first=True).eval()
    x = torch.randn(b, t, d)
    projections = 2 * b * t * (4 * d * d + 2 * d * ff)  # q, k, v, out; two feed-forward
    attention = 2 * 2 * b * t * t * d  # Q K^T and the weighted sum of V
    # under inference_mode the fused fast path would hide all of it, and the CPU's flash
    # attention kernel has no formula of its own
    assert count_flops(lambda: layer(x)) == projections + attention
    assert torch.backends.mha.get_fastpath_enabled()  # restored


def test_ddim_lands_on_the_networks_clean_estimate():
    visited, alphas_bar = ddim_alphas(FreeMotionConfig())
    assert visited.tolist() == list(range(980, -1, -20))  # 50 steps, noisiest first
    assert (alphas_bar[1:] < alphas_bar[:-1]).all() and 0 < alphas_bar[-1] < 1e-3
    target = torch.randn(3, 9, SMALL.feature_dim)

    class Oracle:
        cfg = SMALL

        def __call__(self, x, t, text, others=None):
            return target.repeat(2, 1, 1)  # the same estimate with and without text

    text = torch.randn(3, 5, SMALL.text_dim)
    out, nfe = sample_person(Oracle(), text, torch.zeros_like(text), 9)
    assert nfe == SMALL.steps
    torch.testing.assert_close(out, target, atol=1e-5, rtol=0)


def test_the_control_branch_is_wired_and_starts_silent():
    torch.manual_seed(0)
    net = FreeMotionNet(SMALL, max_frames=20).eval()
    x, t = torch.randn(2, 20, SMALL.feature_dim), torch.tensor([3, 700])
    text, others = torch.randn(2, 5, SMALL.text_dim), torch.randn(2, 2, 20, SMALL.feature_dim)
    with torch.no_grad():
        alone = net(x, t, text)
        torch.testing.assert_close(net(x, t, text, others), alone, atol=0, rtol=0)
        nn.init.normal_(net.zero[0].weight)  # trained: the others now change the estimate
        assert (net(x, t, text, others) - alone).abs().max() > 1e-3


@pytest.mark.parametrize("people", [1, 3])
def test_a_scene_costs_steps_per_person_and_twice_the_transformer_for_each_follower(people):
    net = FreeMotionNet(SMALL, max_frames=20).eval()
    text = torch.randn(1, 5, SMALL.text_dim)
    uncond = torch.zeros_like(text)
    motion, nfe = sample_scene(net, text, uncond, people, 20, torch.Generator().manual_seed(0))
    assert motion.shape == (1, people, 20, SMALL.feature_dim) and nfe == people * SMALL.steps
    assert torch.isfinite(motion).all()
    lead = count_flops(lambda: sample_person(net, text, uncond, 20))
    scene = count_flops(lambda: sample_scene(net, text, uncond, people, 20))
    followers = [count_flops(lambda k=k: sample_person(net, text, uncond, 20, motion[:, :k]))
                 for k in range(1, people)]  # fmt: skip
    assert scene == lead + sum(followers)
    for f in followers:  # the ControlNet copy is a second transformer
        assert 1.9 * lead < f < 2.1 * lead
