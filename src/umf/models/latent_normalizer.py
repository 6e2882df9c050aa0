"""Per-(token, channel) standardisation of VAE latents for the flows.

Flow matching starts from N(0, I) noise, so the data end of the path should have a
comparable scale. A VAE with a small KL weight leaves its posterior means far from it
(the first bundled VAE: mean -2.1, spread 0.44 per sample), and then the coarse end of
the path is mostly a shift, not a shape. Each flow therefore works on standardised
latents; the statistics come from the flow's own training latents and are saved as
buffers with its weights, so sampling hands the VAE latents on its own scale.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class LatentNormalizer(nn.Module):
    """z' = (z - mean) / std per (token, channel); identity until :meth:`fit`."""

    def __init__(self, num_tokens: int, latent_dim: int, min_std: float = 1e-3) -> None:
        super().__init__()
        self.min_std = min_std
        self.register_buffer("mean", torch.zeros(num_tokens, latent_dim))
        self.register_buffer("std", torch.ones(num_tokens, latent_dim))

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

    def normalize(self, z: Tensor) -> Tensor:
        return (z - self.mean) / self.std

    def denormalize(self, z: Tensor) -> Tensor:
        return z * self.std + self.mean
