"""Gaussian noise drawn from one generator, or from one generator per batch row.

Sampling passes one generator per scene so that a scene's noise does not depend on how
many other scenes share its batch (row ``i`` is drawn from ``generators[i]`` alone, with
the same shape it would have in a batch of one). Training passes a single generator.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

Generators = torch.Generator | Sequence[torch.Generator | None] | None


def randn(
    shape: Sequence[int],
    generator: Generators = None,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """N(0, I) of ``shape``; a sequence of generators draws row ``i`` from the ``i``-th."""
    shape = tuple(shape)
    if generator is None or isinstance(generator, torch.Generator):
        return torch.randn(shape, generator=generator, device=device, dtype=dtype)
    if len(generator) != shape[0]:
        raise ValueError(f"{len(generator)} generators for a batch of {shape[0]}")
    rows = [torch.randn(shape[1:], generator=g, device=device, dtype=dtype) for g in generator]
    return torch.stack(rows) if rows else torch.empty(shape, device=device, dtype=dtype)
