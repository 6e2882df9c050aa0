"""A warm start for people 2..N: the S-Flow's reaction sampled again from a proposal.

From its near-deterministic start [eps || C + sigma eps'] the S-Flow's first Euler step
points at the average of the reactions it has seen, and for a walk that average glides: the
decoded body travels at the leader's speed while its legs barely step, and the clean-up,
which keeps planted feet put, then leaves the follower behind
(``research/glide_states.py``). On its training path, where the state already leans towards
one particular reaction, the same network predicts a stride.

So with ``sflow.warm_start`` t0 > 0 each added person is sampled twice. The first (usual)
pass says where the person stands, which way they face and what their role is; a sharp
motion is proposed; and the S-Flow runs again from t0 on the path towards that proposal,
with the context as always. The proposal (``sflow.warm_proposal``):

- ``"retrieved"``: one of the real training reactions nearest to the first pass
  (:mod:`umf.reaction_bank`), already in person 1's frame: the first pass's role and place
  with a real person's stride;
- ``"pflow"``: the P-Flow's motion for the prompt (and the person's own prompt), moved
  rigidly on the floor to where the first pass starts. The P-Flow makes person 1, so this
  proposes person 1's role: a caller's partner stands still instead of walking over
  (results/umf-small-bandai-20261205).
"""

from __future__ import annotations

from typing import Any

import torch

from umf.errors import UMFError
from umf.models.denoiser import FROM_CONFIG
from umf.reaction_bank import REACTIONS
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
    """The proposal for the first pass's reaction ``first`` (B, p, r) of ``frames`` feature
    frames: its latent (B, p, r) on the VAE's scale and the NFE it took (module notes)."""
    cfg = pipe.config.sflow
    if cfg.warm_proposal == "retrieved":
        if pipe.reactions is None:
            raise UMFError(
                f"the model {pipe.name} has sflow.warm_proposal 'retrieved' but no "
                f"{REACTIONS} (umf train reactions --model DIR --corpus CORPUS)"
            )
        prompt = torch.nn.functional.normalize(text.pooled.float(), dim=-1)
        return pipe.reactions.nearest(first, frames, cfg.warm_neighbours, generator,
                                      pipe.sflow.latent_norm.normalize, prompt,
                                      cfg.warm_shortlist), 0  # fmt: skip
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


def sample_added(
    pipe: Any,
    prev: Tensor,
    mask: Tensor,
    text: Any,
    uncond: Any,
    frames: int,
    *,
    steps: int,
    guidance: float | None,
    generator: Any,
    own: dict[str, Any],
    pflow_guidance: float | None,
) -> tuple[Tensor, int]:
    """The next person's latent (B, p, r) and the NFE, as the pipeline and re-rolls sample
    people 2..N: the S-Flow's pass and, with ``sflow.warm_start``, the pass again from its
    proposal. ``own``: the person's own prompt (:func:`umf.person_prompts.person_text`);
    ``pflow_guidance``: the caller's guidance for a P-Flow proposal (None: its config's)."""
    kw = {"steps": steps, "guidance": guidance, "generator": generator, **own}
    w, nfe = pipe.sflow.sample(prev, mask, text, uncond, **kw)
    if pipe.config.sflow.warm_start:
        guess, m = proposal(pipe, w, text, uncond, frames, generator, pflow_guidance, own)
        w, n = pipe.sflow.sample(prev, mask, text, uncond, warm=guess, **kw)
        nfe += m + n
    return w, nfe
