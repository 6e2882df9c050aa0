"""Where a person 2..N's proposal stands clear of everyone generated before them.

The S-Flow learned pairs only, so it puts every added person where it would put a partner
of person 1: person 3 of a row on person 2's spot, a circle's six in front of person 1. A
warm start (:mod:`umf.warm_start`) samples such a person again from a real reaction, and
these rules move that reaction first: a partner keeps its joints off the leader's
(:func:`clear_of`), a walker beyond the one whose spot or body it lands on (:func:`beyond`),
anyone else turned about person 1 to a free bearing (:func:`turned_free`). With
``sflow.warm_extend`` a walker of a single file starts where :func:`formation_end` says,
the next place in the file that persons 1 and 2 began. :func:`crowded` reads where
people start, :func:`touches` their whole bodies, every frame (``sflow.warm_clear``).
"""

from __future__ import annotations

import math

import torch

from umf.reaction_bank import SPOT
from umf.representation import features_to_joints, floor_start, place_features

Tensor = torch.Tensor


# m a partner played at the leader's pace keeps between any of its joints and the leader's:
# level partners touched where the slower real one had passed (the checks count 0.25 m as
# contact, and the second pass drifts a little from its proposal)
PLAY_CLEAR = 0.4
# m from person 1 a partner moved clear of them may start at most: real partners side by side
# start 0.7-1.1 m out, and a runner pushed clear of a leader's swinging arms started beyond
# the 1.6 m a pair walking together is checked for
PLAY_FARTHEST = 1.3


def clear_of(features: Tensor, leader: Tensor, distance: float = PLAY_CLEAR) -> Tensor:
    """``features`` (B, T, 262) moved sideways (along person 1's x, away from them: the side
    each starts on) until no joint comes within ``distance`` of one of ``leader``'s (B, T,
    262) at any frame, but never to start more than :data:`PLAY_FARTHEST` to the side; a row
    starting straight ahead or behind stays."""
    for _ in range(3):  # a shift can bring another frame's arm into play
        a, b = features_to_joints(features), features_to_joints(leader)
        gap = (a[:, :, :, None] - b[:, :, None]).norm(dim=-1).flatten(1).min(dim=1).values
        x = floor_start(features)[:, 0]
        need = (distance - gap).clamp_min(0.0) * (x != 0)
        if not bool((need > 1e-4).any()):
            break
        # a little past, for the next frame's arm, but no farther out than PLAY_FARTHEST
        room = (PLAY_FARTHEST - x.abs()).clamp_min(0.0)
        dx = torch.sign(x) * torch.minimum((need + 0.02) * (need > 1e-4), room)
        features = place_features(features, 0.0, dx, torch.zeros_like(dx))
    return features


def beyond(features: Tensor, others: Tensor, bodies: Tensor | None = None,
           clear: float = 0.0) -> Tensor:  # fmt: skip
    """``features`` (B, T, 262) of people travelling with person 1 moved on the floor, where
    a row starts within ``SPOT`` of one of ``others`` (B, M, 2: where people 2..k - 1
    start, person 1's frame; NaN: nobody), by that person's own start, and by as much again
    while it lands on someone. Person 3 of a row walking side by side walks on person 2's far
    side, of a single file behind person 2: each does to the one before what person 2 does
    to person 1. With ``bodies`` (B, M, T, 22, 3: the joints of the same people 2..k - 1 as
    ``others``) and ``clear`` > 0 (``sflow.warm_clear``), a row that :func:`touches` the body
    of the one whose start is nearest its own, where that one starts more ahead of or behind
    person 1 than beside them (a single file), is moved the same way, by that start, until
    it touches nobody (at most M steps); a row still on someone's spot or body after those
    goes on the same way in 0.25 m steps (at most 4). Person 1 is not among ``bodies``: a
    row travelling with them keeps off them by :func:`clear_of`.
    Beside someone (a row), touching alone moves nobody: moved sideways, the third runner of
    a row kept pace in 8 of 16 seeds (13 without), and the val rows touched about as often
    (results/umf-small-bandai-20261215)."""
    whole = bodies is not None and clear > 0

    def hits(f: Tensor) -> Tensor:
        out = crowded(f, others)
        return out | touches(f, bodies, clear) if whole else out

    gap = torch.nan_to_num(torch.cdist(floor_start(features)[:, None], others)[:, 0],
                           nan=float("inf"))  # (B, M)  # fmt: skip
    near = gap.argmin(dim=1)
    hit = gap.gather(1, near[:, None])[:, 0] < SPOT
    step = others[torch.arange(len(others), device=others.device), near]  # (B, 2)
    if whole:  # on nobody's spot but on the body of the one ahead or behind: a file
        theirs = bodies[torch.arange(len(bodies), device=bodies.device), near][:, None]
        filed = step[:, 1].abs() > step[:, 0].abs()
        hit = hit | (~hit & filed & touches(features, theirs, clear))
    step = torch.where(hit[:, None], step, torch.zeros_like(step))
    for _ in range(others.shape[1]):
        if not bool(hit.any()):
            break
        features = place_features(features, 0.0, step[:, 0] * hit, step[:, 1] * hit)
        hit = hit & hits(features)
    if whole and bool(hit.any()):
        way = torch.where(step.norm(dim=-1, keepdim=True) > 0, step, floor_start(features))
        way = way / way.norm(dim=-1, keepdim=True).clamp_min(1e-6) * 0.25
        for _ in range(4):
            features = place_features(features, 0.0, way[:, 0] * hit, way[:, 1] * hit)
            hit = hit & hits(features)
            if not bool(hit.any()):
                break
    return features


def formation_end(starts: Tensor, with_leader: Tensor) -> Tensor:
    """(B, 2) where person k of a single file starts: ``SPOT`` or more behind person k - 1,
    as far as person 2 started behind person 1 (each does to the one before what person 2
    does to person 1), from ``starts`` (B, k - 1, 2: where people 1..k - 1 start, person
    1's frame, facing +Z). NaN for rows whose person 2 does not travel with person 1
    (``with_leader`` (B,)) or walks beside them more than behind: a row is left to
    :func:`beyond`. The first pass of a person k >= 3 (the S-Flow learned pairs only) lands
    anywhere near person 1, and a file came out of order; a row placed the same way
    sideways was pulled back in by the VAE (a reaction 2.5 m out decoded 2.1 m out) and by
    the second pass, and touched more (results/umf-small-bandai-20261217)."""
    step = starts[:, 1] - starts[:, 0]
    behind = step[:, 1] < -step[:, 0].abs()
    end = starts[:, -1] + torch.stack(
        [torch.zeros_like(step[:, 1]), step[:, 1].clamp_max(-SPOT)], -1
    )
    return torch.where((with_leader & behind)[:, None], end, torch.full_like(end, float("nan")))


def crowded(features: Tensor, others: Tensor, spot: float = SPOT) -> Tensor:
    """(B,) whether each row of ``features`` (B, T, 262) starts within ``spot`` of one of
    ``others`` (B, M, 2): where people 2..k - 1 start (a NaN point, nobody, is never near)."""
    return (torch.cdist(floor_start(features)[:, None], others)[:, 0] < spot).any(dim=-1)


def touches(features: Tensor, bodies: Tensor, clear: float) -> Tensor:
    """(B,) whether some joint of each row of ``features`` (B, T, 262) comes within ``clear``
    (m) of a joint of one of ``bodies`` (B, M, T, 22, 3: other people's joints, same
    frame) at any frame: the relation checks' ``no_contact`` over the whole motion, where
    :func:`crowded` reads the first frame's pelvis only. People who start 1.2 m apart
    around person 1 still bowed into each other, and a circle's six crowded in front of them
    (results/umf-small-bandai-20261215)."""
    joints = features_to_joints(features).flatten(0, 1)  # (B * T, 22, 3)
    out = torch.zeros(len(features), dtype=torch.bool, device=features.device)
    for m in range(bodies.shape[1]):
        gap = torch.cdist(joints, bodies[:, m].flatten(0, 1).to(joints))  # (B * T, 22, 22)
        out |= gap.reshape(len(features), -1).amin(dim=1) < clear  # NaN: nobody, never near
    return out


# m a person turned about person 1 to a free bearing keeps from where anyone before starts:
# an audience's members stand 0.9-1.2 m apart (umf.data.scene_relations); at SPOT they bowed
# into each other (results/umf-small-bandai-20261212)
AROUND = 1.2
# turns about person 1 tried, nearest first, for a proposal standing on someone's spot
BEARINGS = tuple(math.radians(sign * deg) for deg in range(20, 181, 20) for sign in (1, -1))


def turned_free(
    features: Tensor,
    others: Tensor,
    clear: float = AROUND,
    bodies: Tensor | None = None,
    body_clear: float = 0.0,
) -> tuple[Tensor, Tensor]:
    """``features`` (B, T, 262), the rows among them that start within ``SPOT`` of one of
    ``others`` (B, M, 2) turned about person 1's first-frame pelvis (the origin) by the
    smallest of :data:`BEARINGS` that puts their start at least ``clear`` from all of them,
    and (B,) which were turned. A reaction that faces person 1 (an answer, an audience
    member, someone walking over) still faces them from its new bearing; the bank holds pairs
    only, so the third member of an audience had no real reaction standing beside the second
    one to take. With ``bodies`` (B, M, T, 22, 3: the joints of the same people 2..k - 1 as
    ``others``) and ``body_clear`` > 0 (``sflow.warm_clear``), a row that :func:`touches` one
    of them is turned too, to the smallest bearing that also keeps every joint
    ``body_clear`` from theirs throughout; where no bearing does, a row on someone's spot
    takes the start rule's and any other stays. Person 1 is not among ``bodies``: a turn
    about them keeps a row as far from a person 1 who stands still."""
    whole = bodies is not None and body_clear > 0
    spot = crowded(features, others)
    hit = spot | touches(features, bodies, body_clear) if whole else spot
    out, turned = features.clone(), torch.zeros(len(features), dtype=torch.bool)
    for i in hit.nonzero().flatten().tolist():
        fallback = None
        for yaw in BEARINGS:
            moved = place_features(features[i], yaw, 0.0, 0.0)
            if bool(crowded(moved[None], others[i : i + 1], clear)[0]):
                continue
            if not whole or not bool(touches(moved[None], bodies[i : i + 1], body_clear)[0]):
                fallback = None
                out[i], turned[i] = moved, True
                break
            fallback = moved if fallback is None else fallback
        if fallback is not None and bool(spot[i]):  # off someone's spot, as without bodies
            out[i], turned[i] = fallback, True
    return out, turned.to(features.device)
