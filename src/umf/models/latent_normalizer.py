"""Per-(token, channel) standardisation of VAE latents for the flows.

Flow matching starts from N(0, I) noise, so the data end of the path should have a
comparable scale. A VAE with a small KL weight leaves its posterior means far from it
(the first bundled VAE: mean -2.1, spread 0.44 per sample), and then the coarse end of
the path is mostly a shift, not a shape. Each flow therefore works on standardised
latents; the statistics come from the flow's own training latents and are saved as
buffers with its weights, so sampling hands the VAE latents on its own scale.

With a pyramid ``layout`` the normaliser also standardises the fine detail: each token's
difference from the mean of its pair (1-D) or 2x2 block, which is what the finest pyramid
stage adds, is scaled per channel to unit variance. The coarse content (the block means)
is left alone, so the coarse stages see exactly what they saw before. Why: fast motion
inside a gesture (a wave's swing) is a small share of a channel's variance, dominated by
where a person travels; flow noise then hides it until the last steps.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from umf.flows.pyramid import Layout, split_detail

# Largest detail gain: a channel whose tokens hardly differ within a block holds no fine
# detail worth the flow's effort, and a huge gain would only magnify rounding and encoder
# noise (fitted on the bundled P-Flow's training latents: 2.4-4.4)
MAX_DETAIL_GAIN = 10.0


class LatentNormalizer(nn.Module):
    """z' = (z - mean) / std per (token, channel), then, with a ``detail_layout``, the fine
    detail of z' times a per-channel gain (at most ``MAX_DETAIL_GAIN``); identity until
    :meth:`fit`."""

    def __init__(
        self,
        num_tokens: int,
        latent_dim: int,
        min_std: float = 1e-3,
        detail_layout: Layout | None = None,
    ) -> None:
        super().__init__()
        self.min_std = min_std
        self.detail_layout = detail_layout
        self.register_buffer("mean", torch.zeros(num_tokens, latent_dim))
        self.register_buffer("std", torch.ones(num_tokens, latent_dim))
        if detail_layout is not None:
            self.register_buffer("detail_gain", torch.ones(latent_dim))

    @torch.no_grad()
    def fit(self, z: Tensor) -> None:
        """Statistics of latents z (N, p, r)."""
        if z.dim() != 3 or z.shape[1:] != self.mean.shape or z.shape[0] < 2:
            raise ValueError(
                f"need latents (N >= 2, {tuple(self.mean.shape)}), got {tuple(z.shape)}"
            )
        z = z.double()
        self.mean.copy_(z.mean(0))
        self.std.copy_(z.std(0).clamp_min(self.min_std))
        self.fit_detail(z)

    @torch.no_grad()
    def fit_detail(self, z: Tensor) -> None:
        """The detail gains for latents z (N, p, r) under the current mean and std (a
        fine-tune keeps the mean and std its weights were trained with); no-op without a
        detail layout."""
        if self.detail_layout is None:
            return
        _, detail = split_detail((z.to(self.mean) - self.mean) / self.std, self.detail_layout)
        rms = detail.pow(2).mean(dim=(0, 1)).sqrt()
        self.detail_gain.copy_((1.0 / rms.clamp_min(1e-12)).clamp_max(MAX_DETAIL_GAIN))

    def normalize(self, z: Tensor) -> Tensor:
        z = (z - self.mean) / self.std
        if self.detail_layout is None:
            return z
        coarse, detail = split_detail(z, self.detail_layout)
        return coarse + detail * self.detail_gain

    def denormalize(self, z: Tensor) -> Tensor:
        if self.detail_layout is not None:
            coarse, detail = split_detail(z, self.detail_layout)
            z = coarse + detail / self.detail_gain
        return z * self.std + self.mean
