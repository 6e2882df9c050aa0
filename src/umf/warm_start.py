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

``sflow.warm_glide`` > 0 keeps the second pass only for the people whose first pass glides
(:func:`glide_score` above it) and everybody else's first pass as it was: a bow or a
gesture does not glide, and a proposal from elsewhere only costs it its fit to the context.
``sflow.warm_pace`` > 0 retrieves only real reactions that travel as the first pass does
(its decoded path keeps pace and direction where its legs do not): pelvis velocities in
person 1's frame within that fraction of the first pass's. A person for whom the bank has
none keeps the first pass (:func:`warm_rows`).
"""

from __future__ import annotations

from typing import Any

import torch

from umf.errors import UMFError
from umf.models.denoiser import FROM_CONFIG
from umf.reaction_bank import REACTIONS
from umf.representation import features_to_joints, leader_frame, transform_features

Tensor = torch.Tensor


def move_onto(features: Tensor, there: Tensor) -> Tensor:
    """``features`` (B, T, 262) moved rigidly on the floor (a turn about +Y and a shift) so
    that each row's first-frame pelvis and facing are those of ``there``'s row."""
    return torch.stack([
        transform_features(transform_features(f, leader_frame(f)), leader_frame(g),
                           inverse=True)
        for f, g in zip(features, there, strict=True)])  # fmt: skip


# the pelvis's mean floor speed (m/s) under which a person is not travelling, so not gliding
MOVING = 0.5
ANKLES = (7, 8)


def floor_speeds(features: Tensor, fps: float) -> tuple[Tensor, Tensor]:
    """(B,) mean floor speeds (m/s) of the pelvis and of the slower ankle, for features
    (B, T, 262)."""
    floor = features_to_joints(features)[..., [0, 2]]
    speed = (floor[:, 1:] - floor[:, :-1]).norm(dim=-1) * fps  # (B, T - 1, 22)
    slower = torch.minimum(speed[:, :, ANKLES[0]], speed[:, :, ANKLES[1]])
    return speed[:, :, 0].mean(1), slower.mean(1)


def floor_velocity(features: Tensor, fps: float) -> Tensor:
    """(B, 2) the pelvis's mean floor velocity (x, z) in m/s, start to end, for features
    (B, T, 262), in their frame: for people 2..N, person 1's."""
    pelvis = features_to_joints(features)[:, :, 0][..., [0, 2]]
    return (pelvis[:, -1] - pelvis[:, 0]) * fps / max(pelvis.shape[1] - 1, 1)


def glide_score(features: Tensor, fps: float) -> Tensor:
    """(B,) the slower ankle's mean floor speed over the pelvis's for features (B, T, 262);
    0 for a row whose pelvis travels under ``MOVING``. A stride keeps one foot near rest, a
    glide carries both: real followers walking side by side score about 0.13 (at most 0.24),
    real runners 0.41 (at most 0.47); the bundled S-Flow's walkers 0.4-0.6, its runners
    0.6-0.7 (results/umf-small-bandai-20261206)."""
    pelvis, slower = floor_speeds(features, fps)
    score = slower / pelvis.clamp_min(1e-6)
    return torch.where(pelvis >= MOVING, score, torch.zeros_like(score))


def unit_prompt(text: Any) -> Tensor:
    """(B, D) the prompts' pooled text features as unit vectors: what the bank's caption
    shortlist compares."""
    return torch.nn.functional.normalize(text.pooled.float(), dim=-1)


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
        prompt = unit_prompt(text)
        velocity = None
        if cfg.warm_pace > 0:
            decoded = pipe.decode(first, frames, reaction=True)
            velocity = floor_velocity(decoded, pipe.config.fps)
        return pipe.reactions.nearest(first, frames, cfg.warm_neighbours, generator,
                                      pipe.sflow.latent_norm.normalize, prompt,
                                      cfg.warm_shortlist, velocity, cfg.warm_pace), 0  # fmt: skip
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
    proposal for the rows :func:`warm_rows` takes (it runs for every row, so a row's draws
    never depend on its batch). ``own``: the person's own prompt
    (:func:`umf.person_prompts.person_text`); ``pflow_guidance``: the caller's guidance for
    a P-Flow proposal (None: its config's)."""
    kw = {"steps": steps, "guidance": guidance, "generator": generator, **own}
    w, nfe = pipe.sflow.sample(prev, mask, text, uncond, **kw)
    cfg = pipe.config.sflow
    if cfg.warm_start:
        guess, m = proposal(pipe, w, text, uncond, frames, generator, pflow_guidance, own)
        again, n = pipe.sflow.sample(prev, mask, text, uncond, warm=guess, **kw)
        nfe += m + n
        w = torch.where(warm_rows(pipe, w, frames, text)[:, None, None], again, w)
    return w, nfe


def warm_rows(pipe: Any, first: Tensor, frames: int, text: Any = None) -> Tensor:
    """(B,) which first passes the second pass replaces: all, or with ``sflow.warm_glide``
    those that glide, and with ``sflow.warm_pace`` (retrieved proposals) only those for
    which the bank holds a real reaction travelling as they do among those the retrieval
    chooses from (``text``: the prompts, for the caption shortlist): a person faster than
    every such reaction keeps their first pass rather than take a slower one."""
    cfg = pipe.config.sflow
    take = torch.ones(first.shape[0], dtype=torch.bool, device=first.device)
    paced = cfg.warm_proposal == "retrieved" and cfg.warm_pace > 0
    if cfg.warm_glide > 0 or paced:
        decoded = pipe.decode(first, frames, reaction=True)
        if cfg.warm_glide > 0:
            take &= glide_score(decoded, pipe.config.fps) > cfg.warm_glide
        if paced:
            velocity = floor_velocity(decoded, pipe.config.fps)
            prompt = None if text is None else unit_prompt(text)
            take &= pipe.reactions.at_pace(velocity, frames, cfg.warm_pace, prompt,
                                           cfg.warm_shortlist)  # fmt: skip
    return take
