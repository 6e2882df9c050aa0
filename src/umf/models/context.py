"""Context adapter of S-Flow (paper Eq. 12, SPEC 7): previous people's latents -> C.

All previous people's tokens attend to each other in one sequence (B, n_prev * p, r);
the output is split back per person and averaged over the people who exist. Without a
person embedding the result does not depend on the order of the previous people, which
is what lets one S-Flow serve any N autoregressively.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from umf.models.denoiser import encoder_layer


def masked_person_mean(x: Tensor, mask: Tensor) -> Tensor:
    """Mean of (B, n, p, r) over the persons where ``mask`` (B, n) is True."""
    m = mask.to(x.dtype)[:, :, None, None]
    return (x * m).sum(1) / m.sum(1).clamp_min(1.0)


class ContextAdapter(nn.Module):
    """TranEnc over the previous latents, then a masked mean over persons -> (B, p, r).

    The encoder has width r and no final norm: its residual stream starts as the raw
    latents, so at initialisation C is close to the mean of the previous latents (the
    ``enabled=False`` ablation) and training learns corrections on top of it.
    ``positional`` adds a learned token-in-person embedding (the same for every person,
    so order invariance over people is kept).
    """

    def __init__(
        self,
        r: int,
        heads: int = 4,
        ff_dim: int = 1024,
        layers: int = 2,
        *,
        positional: bool = False,
        enabled: bool = True,
        num_tokens: int | None = None,
        dropout: float = 0.1,
    ):
        super().__init__()
        self.enabled = enabled
        self.layers = nn.ModuleList(
            encoder_layer(r, heads, ff_dim, dropout) for _ in range(layers if enabled else 0)
        )
        self.pos: nn.Parameter | None = None
        if enabled and positional:
            if num_tokens is None:
                raise ValueError("a positional context adapter needs num_tokens")
            self.pos = nn.Parameter(torch.zeros(num_tokens, r))
            nn.init.trunc_normal_(self.pos, std=0.02)

    def forward(self, prev: Tensor, prev_mask: Tensor) -> Tensor:
        """prev (B, n_prev, p, r) latents, prev_mask (B, n_prev) True = person exists."""
        if prev.dim() != 4 or prev_mask.shape != prev.shape[:2]:
            raise ValueError(f"prev {tuple(prev.shape)} / prev_mask {tuple(prev_mask.shape)}")
        mask = prev_mask.to(device=prev.device, dtype=torch.bool)
        if not bool(mask.any(1).all()):
            raise ValueError("every sample needs at least one previous person")
        # Absent slots may hold anything (even NaN): zero them so masking is exact.
        prev = torch.where(mask[:, :, None, None], prev, prev.new_zeros(()))
        if not self.enabled:
            return masked_person_mean(prev, mask)
        b, n, p, r = prev.shape
        h = prev if self.pos is None else prev + self.pos
        h = h.reshape(b, n * p, r)
        kpm = None if bool(mask.all()) else ~mask.repeat_interleave(p, dim=1)
        for layer in self.layers:
            h = layer(h, src_key_padding_mask=kpm)
        return masked_person_mean(h.reshape(b, n, p, r), mask)
