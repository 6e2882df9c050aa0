"""People 2..N carried along a turning person 1 (``sflow.warm_follow``), and a fall-back.

No training crop turns more than 20 degrees (``research/runner_turns.py``), so neither the
bank of real reactions nor the S-Flow has seen a partner turn: beside a runner who turns 50
degrees, a reaction played straight at their pace ends 1.2 m behind (results/umf-small-
bandai-20261217). With ``sflow.warm_follow`` d, a played proposal of a row whose person 1
turns more than d degrees is carried along person 1's path (:func:`follow_leader`,
:func:`umf.path_follow.follow_path`), and the straight proposal is kept: where the S-Flow's
pass from the carried one comes within the relation checks' contact distance of someone
(the VAE's round trip and the pass take up to 0.4 m of its clearance beside a leader who
turns hard), the row is sampled again from the straight one with the same draws
(:func:`fall_back`, :func:`twin`), which is the pass it would have had without the option.
"""

from __future__ import annotations

from typing import Any

import torch

from umf.clearance import touches
from umf.data.relations import CONTACT_DISTANCE
from umf.path_follow import follow_path, path_turn
from umf.representation import (
    assemble_features,
    features_to_joints,
    features_to_joints_integrated,
    joints_to_rot6d,
)

Tensor = torch.Tensor


def row_joints(features: Tensor) -> Any:
    """One row's features (T, 262) as float64 joints (T + 1, 22, 3) in numpy, for the
    motion edits done there (:func:`umf.warm_start.play_at`, :func:`follow_leader`)."""
    return features_to_joints_integrated(features.detach()).double().cpu().numpy()


def row_features(joints: Any, like: Tensor) -> Tensor:
    """Numpy joints (T + 1, 22, 3) back as features (T, 262) of ``like``'s dtype, rotations
    recovered from the joints."""
    x = torch.from_numpy(joints).to(like.dtype)
    return assemble_features(x, joints_to_rot6d(x))


def follow_leader(features: Tensor, leader: Tensor) -> Tensor:
    """Features (B, T, 262) carried along the paths of ``leader`` (B, T, 262), both in person
    1's frame (:func:`umf.path_follow.follow_path`), rotations recovered from the new joints.
    Which rows to carry is :func:`turning`'s to say."""
    return torch.stack([
        row_features(follow_path(row_joints(f), row_joints(g)), f).to(f.device)
        for f, g in zip(features, leader, strict=True)])  # fmt: skip


def turning(leader: Tensor, turn: float) -> Tensor:
    """(B,) whether each leader's (B, T, 262) path turns more than ``turn`` degrees
    (:func:`umf.path_follow.path_turn`)."""
    return torch.tensor([path_turn(row_joints(g)) > turn for g in leader], device=leader.device)


def twin(generator: Any) -> Any:
    """A copy of a generator (or of each in a list) in its current state: a pass drawn
    from the copy draws what the original's next pass will."""
    if isinstance(generator, torch.Generator):
        copy = torch.Generator(device=generator.device)
        copy.set_state(generator.get_state())
        return copy
    if isinstance(generator, list | tuple):
        return [twin(g) for g in generator]
    return generator


def fall_back(
    pipe: Any, again: Tensor, straight: tuple[Tensor, Tensor], taken: Tensor, prev: Tensor,
    mask: Tensor, text: Any, uncond: Any, frames: int, leader: Tensor, bodies: Tensor | None,
    kw: dict[str, Any], warm_t: float | None,
) -> tuple[Tensor, int]:  # fmt: skip
    """The second pass ``again`` (B, p, r) with each row that was carried along person 1
    (``straight``: those rows and their proposal before carrying,
    :func:`umf.warm_start.proposal`) and is
    ``taken`` sampled again from the straight proposal, with the same draws (``kw``'s
    generators, one per row as the pipeline passes them: :func:`twin`; one generator for the
    batch, or none, draws anew), where the carried pass comes within the relation checks'
    contact distance of person 1 (``leader``) or, where ``sflow.warm_clear`` gives their
    ``bodies``, of people 2..k - 1 at some frame, and the NFE. The S-Flow never saw a
    partner turn (no training crop turns more than 20 degrees): from a carried proposal its
    pass may run onto a turning person 1."""
    rows, z = straight
    keep = taken[rows]
    rows, z = rows[keep], z[keep]
    if not len(rows):
        return again, 0
    everyone = features_to_joints(leader[rows])[:, None]
    if bodies is not None:
        everyone = torch.cat([everyone, bodies[rows].to(everyone)], dim=1)
    hit = touches(pipe.decode(again[rows], frames, reaction=True), everyone, CONTACT_DISTANCE)
    if not bool(hit.any()):
        return again, 0
    rows, z = rows[hit], z[hit]
    sub = {k: _subset(v, rows) for k, v in kw.items()}
    alt, nfe = pipe.sflow.sample(prev[rows], mask[rows], text.rows(rows), _subset(uncond, rows),
                                 warm=z, warm_t=warm_t, **sub)  # fmt: skip
    again = again.clone()
    again[rows] = alt.to(again)
    return again, nfe


def _subset(value: Any, rows: Tensor) -> Any:
    """The batch's ``rows`` of a sampling argument: features, a per-row list (generators),
    a tensor; one shared row (the empty prompt), a scalar or None as it is."""
    if isinstance(value, list | tuple):
        return [value[i] for i in rows.tolist()]
    if isinstance(value, Tensor):
        return value[rows]
    if hasattr(value, "rows") and value.tokens.shape[0] > 1:  # text features
        return value.rows(rows)
    return value
