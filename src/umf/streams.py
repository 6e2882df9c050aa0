"""Per-scene random streams: a scene's noise is a function of (seed, sample index) alone.

Each scene gets its own generator, seeded from the user's seed and the scene's sample
index through numpy's SeedSequence (well-mixed, so seeds 0 and 1 give unrelated streams),
and created on the device the model runs on (a CPU generator cannot fill a CUDA tensor).
"""

from __future__ import annotations

import secrets
from collections.abc import Sequence

import numpy as np
import torch


def stream_seed(seed: int, index: int) -> int:
    """The 64-bit seed of sample ``index`` of a request seeded with ``seed``."""
    words = np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(2, np.uint32)
    return int(words[0]) | (int(words[1]) << 32)


def device_generator(seed: int, device: torch.device | str) -> torch.Generator | None:
    """A generator on ``device`` seeded with ``seed``; None on ``meta`` (no values to seed)."""
    device = torch.device(device)
    if device.type == "meta":
        return None
    return torch.Generator(device=device).manual_seed(seed)


def scene_generators(
    seed: int, indices: Sequence[int], device: torch.device | str
) -> list[torch.Generator | None]:
    """One generator per scene, on ``device``."""
    return [device_generator(stream_seed(seed, i), device) for i in indices]


def fresh_seed() -> int:
    """A random seed for requests without one (recorded in the scene, so it can be redone)."""
    return secrets.randbits(63)
