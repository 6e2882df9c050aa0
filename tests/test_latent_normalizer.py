import pytest
import torch

from umf.flows.pyramid import down, up
from umf.models.latent_normalizer import LatentNormalizer


def _latents(n: int = 400, tokens: int = 16, dim: int = 4, seed: int = 0) -> torch.Tensor:
    """Slow content of large spread plus a small fast swing in channel 0 (a wave's)."""
    g = torch.Generator().manual_seed(seed)
    slow = torch.randn(n, tokens // 2, dim, generator=g).repeat_interleave(2, dim=1) * 2 + 1
    swing = torch.tensor([1.0, -1.0]).repeat(tokens // 2)[None, :, None]
    phase = torch.randint(0, 2, (n, 1, 1), generator=g) * 2 - 1
    z = slow.clone()
    z[..., :1] += 0.3 * phase * swing
    return z + 0.3 * torch.randn(z.shape, generator=g)


@pytest.mark.parametrize("layout,tokens", [("1d", 16), ("2d", 16)])
def test_detail_norm_round_trips_and_leaves_the_coarse_content_alone(layout, tokens):
    z = _latents(tokens=tokens)
    plain, detail = LatentNormalizer(tokens, 4), LatentNormalizer(tokens, 4, detail_layout=layout)
    plain.fit(z)
    detail.fit(z)
    torch.testing.assert_close(detail.denormalize(detail.normalize(z)), z, atol=1e-5, rtol=0)
    # the block means are what the coarse pyramid stages see: the same as before
    torch.testing.assert_close(down(detail.normalize(z), layout), down(plain.normalize(z), layout),
                               atol=1e-5, rtol=0)  # fmt: skip


def test_detail_norm_gives_the_fine_detail_unit_variance_per_channel():
    z = _latents()
    norm = LatentNormalizer(16, 4, detail_layout="1d")
    norm.fit(z)
    x = norm.normalize(z)
    detail = x - up(down(x, "1d"), "1d")
    torch.testing.assert_close(detail.pow(2).mean(dim=(0, 1)), torch.ones(4), atol=1e-4, rtol=0)
    plain = LatentNormalizer(16, 4)
    plain.fit(z)
    y = plain.normalize(z)
    before = (y - up(down(y, "1d"), "1d")).pow(2).mean(dim=(0, 1))
    assert torch.all(before < 0.1)  # fine detail: a few % of each channel's variance
    assert torch.all(norm.detail_gain > 3)
    assert norm.detail_gain[0] < norm.detail_gain[1:].min()  # the swing's channel has more


def test_fit_detail_keeps_the_mean_and_std():
    z = _latents()
    norm = LatentNormalizer(16, 4, detail_layout="1d")
    norm.mean.fill_(0.5)
    norm.std.fill_(2.0)
    norm.fit_detail(z)
    assert torch.all(norm.mean == 0.5) and torch.all(norm.std == 2.0)
    x = (z - 0.5) / 2.0
    rms = (x - up(down(x, "1d"), "1d")).pow(2).mean(dim=(0, 1)).sqrt()
    torch.testing.assert_close(norm.detail_gain, 1 / rms, rtol=1e-5, atol=0)


def test_without_a_detail_layout_there_is_no_gain():
    norm = LatentNormalizer(16, 4)
    assert "detail_gain" not in norm.state_dict()
    norm.fit_detail(_latents())  # a no-op
    z = _latents()
    norm.fit(z)
    torch.testing.assert_close(norm.normalize(z), (z - z.mean(0)) / z.std(0), atol=1e-5, rtol=0)


def test_detail_gain_is_capped_where_a_channel_has_no_detail():
    from umf.models.latent_normalizer import MAX_DETAIL_GAIN

    z = _latents()
    z[..., 1] = z[..., 1].unflatten(1, (8, 2)).mean(2).repeat_interleave(2, dim=1)  # none
    norm = LatentNormalizer(16, 4, detail_layout="1d")
    norm.fit(z)
    assert norm.detail_gain[1] == MAX_DETAIL_GAIN
    torch.testing.assert_close(norm.denormalize(norm.normalize(z)), z, atol=1e-4, rtol=0)
