"""The linear path, time sampling and the masked loss."""

from __future__ import annotations

import pytest
import torch

from umf.flows import (
    flow_matching_loss,
    interpolate,
    linear_path_sample,
    sample_time,
    target_velocity,
)


def _pair(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(3, 16, 8, generator=g), torch.randn(3, 16, 8, generator=g)


def test_endpoints_and_shape() -> None:
    x0, x1 = _pair()
    assert torch.equal(interpolate(x0, x1, torch.zeros(3)), x0)
    assert torch.equal(interpolate(x0, x1, torch.ones(3)), x1)
    s = linear_path_sample(x0, x1, torch.rand(3))
    assert s.x_t.shape == x0.shape and s.target.shape == x0.shape


def test_target_is_time_derivative() -> None:
    x0, x1 = _pair(1)
    x0, x1 = x0.double(), x1.double()
    t = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    h = 1e-6
    fd = (interpolate(x0, x1, t + h) - interpolate(x0, x1, t - h)) / (2 * h)
    torch.testing.assert_close(fd, target_velocity(x0, x1), atol=1e-8, rtol=0)


def test_per_sample_time_broadcast() -> None:
    x0, x1 = _pair(2)
    t = torch.tensor([0.0, 0.5, 1.0])
    xt = interpolate(x0, x1, t)
    torch.testing.assert_close(xt[1], 0.5 * (x0[1] + x1[1]))
    assert torch.equal(xt[0], x0[0]) and torch.equal(xt[2], x1[2])


@pytest.mark.parametrize("dist", ["uniform", "logit_normal"])
def test_sample_time_range_and_determinism(dist: str) -> None:
    a = sample_time(20_000, distribution=dist, generator=torch.Generator().manual_seed(3))
    b = sample_time(20_000, distribution=dist, generator=torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    assert a.shape == (20_000,) and bool(((a >= 0) & (a <= 1)).all())
    assert abs(a.mean().item() - 0.5) < 0.01  # both are symmetric about 1/2
    if dist == "logit_normal":  # more mass in the middle than uniform
        assert ((a - 0.5).abs() < 0.25).float().mean().item() > 0.6


def test_sample_time_rejects_unknown() -> None:
    with pytest.raises(ValueError):
        sample_time(4, distribution="beta")  # type: ignore[arg-type]


def test_loss_mask() -> None:
    pred, target = _pair(4)
    assert torch.isclose(flow_matching_loss(pred, target), (pred - target).square().mean())
    mask = torch.zeros(3, 16, dtype=torch.bool)
    mask[:, :8] = True
    mask[2] = True
    polluted = pred.clone()
    polluted[:2, 8:] = 1e6  # padding must not leak into the loss
    got = flow_matching_loss(polluted, target, mask)
    per = [
        (pred[0, :8] - target[0, :8]).square().mean(),
        (pred[1, :8] - target[1, :8]).square().mean(),
        (pred[2] - target[2]).square().mean(),
    ]
    torch.testing.assert_close(got, torch.stack(per).mean())


def test_times_keep_the_tensors_dtype_and_the_sample_its_time() -> None:
    """A float64 model gets float64 times (a float32 time would round the path), and the
    path sample carries the very times it was drawn at."""
    x0, x1 = (x.double() for x in _pair(5))
    t = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    s = linear_path_sample(x0, x1, t)
    assert s.t is t and s.x_t.dtype == torch.float64
    third = torch.tensor(1 / 3, dtype=torch.float64)  # not rounded to float32 on the way
    assert torch.equal(interpolate(x0, x1, 1 / 3), third * x1 + (1 - third) * x0)
    for dist in ("uniform", "logit_normal"):
        assert sample_time(4, distribution=dist, dtype=torch.float64).dtype == torch.float64


def test_default_times_are_uniform_and_logit_normal_is_exactly_its_formula() -> None:
    """The default is the uniform draw of the same stream; logit-normal times are
    sigmoid(loc + scale * z) of the stream's normal draws (not merely distributed alike:
    a run must reproduce its times)."""
    g = lambda: torch.Generator().manual_seed(7)  # noqa: E731
    assert torch.equal(sample_time(64, generator=g()), torch.rand(64, generator=g()))
    z = torch.randn(64, generator=g())
    got = sample_time(64, distribution="logit_normal", loc=0.3, scale=0.8, generator=g())
    assert torch.equal(got, torch.sigmoid(0.3 + 0.8 * z))
    with pytest.raises(ValueError, match="unknown time distribution 'beta'"):
        sample_time(4, distribution="beta")  # type: ignore[arg-type]


def test_a_sample_with_one_valid_entry_counts_it_once() -> None:
    """Each sample is averaged over its own valid entries: one valid token is its error."""
    pred, target = torch.zeros(2, 4), torch.tensor([[3.0, 0, 0, 0], [1.0, 1.0, 1.0, 1.0]])
    mask = torch.tensor([[True, False, False, False], [True, True, True, True]])
    assert torch.isclose(flow_matching_loss(pred, target, mask), torch.tensor((9.0 + 1.0) / 2))
