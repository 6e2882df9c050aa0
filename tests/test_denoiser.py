"""FlowTransformer: masking, pyramid positions, stage/dataset tokens, branches, CFG text."""

from __future__ import annotations

import pytest
import torch

from umf.config import DenoiserConfig
from umf.flows import down
from umf.models.denoiser import (
    FROM_CONFIG,
    FlowTransformer,
    drop_text,
    pad_text,
    resolve_guidance,
    timestep_embedding,
)
from umf.text import TextFeatures

D_TEXT, P, R = 16, 16, 8
ATOL = 1e-5


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


def tiny_denoiser(**kw: object) -> DenoiserConfig:
    base = dict(
        d_model=32,
        num_layers=3,
        num_heads=4,
        ff_dim=64,
        dropout=0.0,
        text_width=32,
        text_heads=4,
        text_ff_dim=64,
        text_layers=1,
        branch_layers=1,
    )
    base.update(kw)
    return DenoiserConfig(**base)  # type: ignore[arg-type]


def make_text(b: int, length: int = 7, seed: int = 0, dim: int = D_TEXT) -> TextFeatures:
    """Random encoder-like features: real tokens first, exact zeros at padding."""
    g = torch.Generator().manual_seed(seed)
    lens = torch.randint(1, length + 1, (b,), generator=g)
    lens[0] = length
    mask = torch.arange(length)[None] < lens[:, None]
    tokens = torch.randn(b, length, dim, generator=g) * mask[..., None]
    return TextFeatures(tokens, mask, tokens.sum(1) / lens[:, None])


def model(
    num_stages: int = 1, num_datasets: int = 0, layout: str = "1d", **kw: object
) -> FlowTransformer:
    torch.manual_seed(0)
    net = FlowTransformer(
        tiny_denoiser(**kw),
        R,
        R,
        D_TEXT,
        P,
        num_stages=num_stages,
        num_datasets=num_datasets,
        layout=layout,  # type: ignore[arg-type]
    )
    return net.eval()


def test_shapes_and_exact_layer_count() -> None:
    net = model(num_layers=4)
    b = 3
    out = net(torch.randn(b, P, R), torch.rand(b), make_text(b))
    assert out.shape == (b, P, R)
    layers = [m for m in net.backbone.modules() if isinstance(m, torch.nn.TransformerEncoderLayer)]
    assert len(layers) == 4 and len(net.backbone.merge) == 2
    assert len(model(num_layers=3).backbone.middle) == 1


def test_timestep_embedding_distinguishes_times() -> None:
    e = timestep_embedding(torch.tensor([0.0, 0.001, 0.5, 1.0]), 32)
    assert e.shape == (4, 32)
    assert torch.cdist(e, e).fill_diagonal_(1.0).min() > 0.01


@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_padded_tokens_do_not_influence_valid_ones(layout: str) -> None:
    net = model(num_stages=2, num_datasets=2, layout=layout)
    b = 4
    x, t, text = torch.randn(b, P, R), torch.rand(b), make_text(b)
    mask = torch.ones(b, P, dtype=torch.bool)
    mask[1, 10:] = False
    mask[3, 3:] = False
    ds = torch.tensor([0, 1, 1, 0])
    out = net(x, t, text, dataset=ds, token_mask=mask)
    x2 = torch.where(mask[..., None], x, 100 * torch.randn_like(x))
    out2 = net(x2, t, text, dataset=ds, token_mask=mask)
    torch.testing.assert_close(out[mask], out2[mask], atol=ATOL, rtol=0)
    # padded text tokens are also ignored
    out3 = net(x, t, pad_text(text, 12), dataset=ds, token_mask=mask)
    torch.testing.assert_close(out[mask], out3[mask], atol=ATOL, rtol=0)


@pytest.mark.parametrize("layout", ["1d", "2d"])
def test_coarse_stage_padded_equals_unpadded(layout: str) -> None:
    """Training sees coarse stages zero-padded to p tokens, sampling sees them short."""
    net = model(num_stages=2, num_datasets=2, layout=layout)
    b, n = 3, P // (2 if layout == "1d" else 4)
    x, t, text, ds = torch.randn(b, n, R), torch.rand(b), make_text(b), torch.tensor([0, 1, 1])
    stage = torch.full((b,), 2)
    short = net(x, t, text, stage=stage, dataset=ds)
    padded = torch.cat([x, torch.zeros(b, P - n, R)], dim=1)
    long = net(padded, t, text, stage=stage, dataset=ds)  # mask derived from the stage
    torch.testing.assert_close(long[:, :n], short, atol=ATOL, rtol=0)
    # the coarse positions are Down of the fine ones, with the pyramid's layout
    pos = net.positions()
    torch.testing.assert_close(pos[1, :n], down(net.pos[None], layout)[0])  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        net(x, t, text, stage=torch.ones(b, dtype=torch.long), dataset=ds)  # too few tokens


def rows(text: TextFeatures, idx: slice) -> TextFeatures:
    return TextFeatures(text.tokens[idx], text.mask[idx], text.pooled[idx])


def test_mixed_stage_batch_matches_single_stage_batches() -> None:
    net = model(num_stages=2, num_datasets=2)
    x, t, text, ds = torch.randn(3, P, R), torch.rand(3), make_text(3), torch.tensor([1, 0, 1])
    stage = torch.tensor([1, 2, 2])
    mixed = net(x, t, text, stage=stage, dataset=ds)
    for i in range(3):
        n = P // 2 ** (int(stage[i]) - 1)
        sl = slice(i, i + 1)
        one = net(x[sl, :n], t[sl], rows(text, sl), stage=stage[sl], dataset=ds[sl])
        torch.testing.assert_close(mixed[i, :n], one[0], atol=ATOL, rtol=0)


def test_stage_and_dataset_tokens_change_output() -> None:
    net = model(num_stages=2, num_datasets=2)
    b = 2
    x, t, text = torch.randn(b, P // 2, R), torch.rand(b), make_text(b)
    stage = torch.full((b,), 2)
    zero, one = torch.zeros(b, dtype=torch.long), torch.ones(b, dtype=torch.long)
    a = net(x, t, text, stage=stage, dataset=zero)
    with torch.no_grad():
        net.stage_emb.weight[1].add_(0.5)  # type: ignore[union-attr]
    b_stage = net(x, t, text, stage=stage, dataset=zero)
    assert (a - b_stage).abs().max() > 1e-3
    c = net(x, t, text, stage=stage, dataset=one)
    assert (b_stage - c).abs().max() > 1e-3
    with pytest.raises(ValueError, match="dataset"):
        net(x, t, text, stage=stage)


def test_dataset_branches_are_selected_per_sample() -> None:
    net = model(num_datasets=2)
    b = 4
    x, t, text = torch.randn(b, P, R), torch.rand(b), make_text(b)
    ds = torch.tensor([0, 1, 1, 0])
    mixed = net(x, t, text, dataset=ds)
    all0 = net(x, t, text, dataset=torch.zeros(b, dtype=torch.long))
    all1 = net(x, t, text, dataset=torch.ones(b, dtype=torch.long))
    expect = torch.where((ds == 1)[:, None, None], all1, all0)
    torch.testing.assert_close(mixed, expect, atol=ATOL, rtol=0)
    # perturbing branch 1 leaves dataset-0 samples untouched
    with torch.no_grad():
        for p in net.heads[1].parameters():
            p.add_(0.1)
    after = net(x, t, text, dataset=ds)
    torch.testing.assert_close(after[ds == 0], mixed[ds == 0], atol=ATOL, rtol=0)
    assert (after[ds == 1] - mixed[ds == 1]).abs().max() > 1e-3


def test_idle_branch_still_gets_a_gradient() -> None:
    """A batch of one dataset must still touch the other branch (DDP without unused
    parameters): its gradient exists and is exactly zero."""
    net = model(num_stages=2, num_datasets=2).train()
    b = 3
    out = net(torch.randn(b, P, R), torch.rand(b), make_text(b), dataset=torch.zeros(b).long())
    out.square().mean().backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None]
    assert not missing
    assert all(float(p.grad.abs().max()) == 0.0 for p in net.heads[1].parameters())  # type: ignore[union-attr]
    assert any(float(p.grad.abs().max()) > 0.0 for p in net.heads[0].parameters())  # type: ignore[union-attr]


def test_precomputed_text_token_matches_features() -> None:
    net = model()
    x, t, text = torch.randn(3, P, R), torch.rand(3), make_text(3)
    a = net(x, t, text)
    b = net(x, t, net.encode_text(text))
    torch.testing.assert_close(a, b)


def test_drop_text_swaps_rows() -> None:
    text = make_text(4, length=5, seed=1)
    empty = make_text(1, length=8, seed=2)
    drop = torch.tensor([False, True, False, True])
    out = drop_text(text, empty, drop)
    assert out.tokens.shape == (4, 8, D_TEXT) and out.mask.shape == (4, 8)
    for i in range(4):
        src, j = (empty, 0) if drop[i] else (text, i)
        n = src.tokens.shape[1]
        assert torch.equal(out.tokens[i, :n], src.tokens[j])
        assert torch.equal(out.mask[i, :n], src.mask[j])
        assert not out.mask[i, n:].any() and not out.tokens[i, n:].any()
        assert torch.equal(out.pooled[i], src.pooled[j])
    # B-row unconditional features work too; nothing dropped is the identity (after padding)
    same = drop_text(text, make_text(4, length=3, seed=3), torch.zeros(4, dtype=torch.bool))
    assert torch.equal(same.tokens, text.tokens) and torch.equal(same.mask, text.mask)


def test_resolve_guidance() -> None:
    assert resolve_guidance(FROM_CONFIG, 3.0) == 3.0
    assert resolve_guidance(FROM_CONFIG, 1.0) is None
    assert resolve_guidance(None, 3.0) is None
    assert resolve_guidance(1.0, 3.0) is None
    assert resolve_guidance(2.0, 3.0) == 2.0
