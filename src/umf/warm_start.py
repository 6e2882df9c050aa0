"""A warm start for people 2..N: the S-Flow's reaction sampled again from a proposal.

From its near-deterministic start [eps || C + sigma eps'] the S-Flow's first Euler step
points at the average of the reactions it has seen, and for a walk that average glides: the
decoded body travels at the leader's speed while its legs barely step, and the clean-up,
which keeps planted feet put, then leaves the follower behind
(``research/glide_states.py``). On its training path, where the state already leans towards
one particular reaction, the same network predicts a stride.

So with ``sflow.warm_start`` t0 > 0 each added person is sampled twice. The first (usual)
pass says where the person stands and which way they face; the P-Flow, which makes sharp
single people, proposes a motion for the prompt (and the person's own prompt); the proposal
is moved rigidly on the floor to where the first pass starts; and the S-Flow runs again
from t0 on the path towards that proposal, with the context as always.
"""

from __future__ import annotations

from typing import Any

import torch

from umf.models.denoiser import FROM_CONFIG
from umf.representation import leader_frame, transform_features

Tensor = torch.Tensor


def move_onto(features: Tensor, there: Tensor) -> Tensor:
    """``features`` (B, T, 262) moved rigidly on the floor (a turn about +Y and a shift) so
    that each row's first-frame pelvis and facing are those of ``there``'s row."""
    return torch.stack([
        transform_features(transform_features(f, leader_frame(f)), leader_frame(g),
                           inverse=True)
        for f, g in zip(features, there, strict=True)])  # fmt: skip


def proposal(
    pipe: Any,
    first: Tensor,
    text: Any,
    uncond: Any,
    frames: int,
    generator: Any,
    guidance: float | None,
    own: dict[str, Any],
) -> tuple[Tensor, int]:
    """The P-Flow's motion for the scene prompt (and the person's ``own`` prompt), placed
    where the first pass's reaction ``first`` (B, p, r) starts: its latent (B, p, r) on the
    VAE's scale and the NFE."""
    z, nfe = pipe.pflow.sample(
        text,
        uncond,
        dataset=torch.ones(first.shape[0], dtype=torch.long, device=first.device),
        steps=pipe.config.pflow.steps,
        guidance=FROM_CONFIG if guidance is None else guidance,
        generator=generator,
        **own,
    )
    moved = move_onto(pipe.decode(z, frames), pipe.decode(first, frames, reaction=True))
    return pipe._encode(moved), nfe
