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
none keeps the first pass (:func:`warm_rows`). ``sflow.warm_together`` c > 0 compares the
bank with person 1's velocity instead, for the people whose first pass travels with person 1
(:func:`travels_with`: a cosine of at least c), among the reactions that start on the first
pass's side of person 1 (:func:`start_side`, the bank's ``start_*``; the first pass says
where the person stands): the first pass beside a runner lags and veers, and a reaction at
its pace did too (results/umf-small-bandai-20261211). A reaction nearer the leader's pace
than the first pass then fits such a person even outside the tolerance. ``sflow.warm_side``
retrieves, for a prompt that names a side ("... the second person on the first one's
left."), only reactions whose captions are at least as near the prompt as its mirror
image: people on that side.

``sflow.warm_start_group`` > 0 is that second pass's time for a person whose context holds
two people or more (person k >= 3; in ``umf reroll``, anyone re-rolled beside two others),
which the S-Flow never saw in training (groups are held out): from 0.5 its second pass
drifted back to where it would put a partner of person 1, often on someone's spot; from
later on the path it keeps more of its proposal, which ``sflow.warm_apart`` placed clear of
them (results/umf-small-bandai-20261214). ``sflow.warm_clear`` c > 0 keeps them off
everybody's whole body, every joint c away at every frame (:mod:`umf.clearance`): a first
pass that touches someone is sampled again, from itself moved where no real reaction at its
pace was found (results/umf-small-bandai-20261215). ``sflow.warm_extend`` starts a walker of
a single file (person 2 behind person 1, both travelling) behind person k - 1, as far as
person 2 started behind person 1 (:func:`umf.clearance.formation_end`), and takes that pass
(results/umf-small-bandai-20261217).

``sflow.own_warm`` > 0 treats a person 2..N given an own prompt apart: sampled again from
that time towards the P-Flow's single-person motion for the own prompt alone
(:func:`pflow_proposal`), whether the first pass glides or not. The S-Flow's own-prompt
head learned beside scene captions that never name a gesture, and its person 2 told "A
person raises both hands." kept its wrists below its head; the P-Flow, which learned the
single clips' captions, raises them. The scene prompt stays out of the proposal: it names
person 1's part ("One person kicks and the other steps back."), and with it the proposal
took that part (per-person matching 0.76-0.81, alone 0.96; results/umf-small-bandai-20261207).
The S-Flow's second pass, given the scene prompt and the context, puts the person in the
scene.
"""

from __future__ import annotations

from typing import Any

import torch

from umf.clearance import beyond, clear_of, crowded, formation_end, touches, turned_free
from umf.config import MULTI_PERSON, SINGLE_PERSON
from umf.data.extension import played_at
from umf.data.relations import ONSET_SMOOTHING, SIDE_MARGIN, action_onset
from umf.errors import UMFError
from umf.models.denoiser import FROM_CONFIG
from umf.reaction_bank import REACTIONS
from umf.representation import (
    features_to_joints,
    floor_start,
    hold_to_length,
    leader_frame,
    place_features,
    shift_in_time,
    transform_features,
)
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT
from umf.text import mirror_caption
from umf.warm_follow import fall_back, follow_leader, row_features, row_joints, turning, twin

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
ANKLES = (FOOT_LEFT[0], FOOT_RIGHT[0])


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


def travels_with(first: Tensor, leader: Tensor, cosine: float) -> Tensor:
    """(B,) whether each first pass (floor velocity ``first``, (B, 2) m/s) travels with
    person 1 (``leader``, (B, 2)): both at least ``MOVING``, their directions' cosine at
    least ``cosine``. Beside a runner the first pass lags and drifts outwards
    (results/umf-small-bandai-20261210, runner-placement.txt), and a reaction retrieved at
    its pace keeps both; at the leader's pace it keeps up."""
    moving = (first.norm(dim=-1) >= MOVING) & (leader.norm(dim=-1) >= MOVING)
    return moving & (torch.nn.functional.cosine_similarity(first, leader, dim=-1) >= cosine)


def together_rows(pipe: Any, decoded: Tensor, leader: Tensor | None) -> Tensor | None:
    """(B,) which first passes (``decoded`` (B, T, 262)) travel with person 1 (``leader``)
    by :func:`travels_with` at ``sflow.warm_together``; None where that is off (or there is
    no pace to compare, ``sflow.warm_pace`` 0, or no leader)."""
    cfg, fps = pipe.config.sflow, pipe.config.fps
    if leader is None or cfg.warm_together <= 0 or cfg.warm_pace <= 0:
        return None
    return travels_with(floor_velocity(decoded, fps), floor_velocity(leader, fps),
                        cfg.warm_together)  # fmt: skip


def play_at(features: Tensor, rate: Tensor) -> Tensor:
    """Features (B, T, 262) played ``rate`` (B,) times as fast (:func:`played_at`: clamped
    to a fifth slower and a quarter faster, the gait carried on past the end), rotations
    recovered from the played joints."""
    t = features.shape[1]
    return torch.stack([
        row_features(played_at(row_joints(f), r, t + 1), features)
        for f, r in zip(features, rate.tolist(), strict=True)]).to(features.device)  # fmt: skip


def start_side(features: Tensor) -> Tensor:
    """(B,) +1 where a person 2..N (features (B, T, 262), person 1's frame) starts more than
    ``SIDE_MARGIN`` to person 1's left (+x), -1 to the right, 0 in between."""
    x = floor_start(features)[:, 0]
    return torch.sign(x) * (x.abs() > SIDE_MARGIN)


def glide_score(features: Tensor, fps: float) -> Tensor:
    """(B,) the slower ankle's mean floor speed over the pelvis's for features (B, T, 262);
    0 for a row whose pelvis travels under ``MOVING``. A stride keeps one foot near rest, a
    glide carries both: real followers walking side by side score about 0.14 (at most 0.23),
    real runners 0.41 (at most 0.47); the S-Flow of 20261204b's walkers 0.44-0.58, its
    runners 0.61-0.71 (``research/glide_scores.py``, results/umf-small-bandai-20261206)."""
    pelvis, slower = floor_speeds(features, fps)
    score = slower / pelvis.clamp_min(1e-6)
    return torch.where(pelvis >= MOVING, score, torch.zeros_like(score))


def proposal(
    pipe: Any,
    first: Tensor,
    decoded: Tensor,
    text: Any,
    uncond: Any,
    generator: Any,
    guidance: float | None,
    own: dict[str, Any],
    mirror: Any = None,
    answers_first: bool = True,
    leader: Tensor | None = None,
    others: Tensor | None = None,
    bodies: Tensor | None = None,
    ends: Tensor | None = None,
) -> tuple[Tensor, int, Tensor, tuple[Tensor, list[int]] | None]:
    """The proposal for the first pass's reaction ``first`` (B, p, r), ``decoded`` (B, T, 262)
    as the pipeline decodes people 2..N: its latent (B, p, r) on the VAE's scale, the NFE it
    took, (B,) whether it fits the row (a retrieved one at the first pass's pace, with
    ``sflow.warm_pace``; module notes) and, with ``sflow.warm_timing`` and a bank that
    stores waits, the timing :func:`answers` gives: (B,) how many frames after its own
    person 1's each answer started (0 for a row that does not answer) and the stored length
    of each row's reaction; else None.
    ``mirror``: the prompts' mirror images (:func:`mirror_text`), for retrieval on the side
    a prompt names; ``answers_first`` False: no answer is looked for (a re-rolled person 1);
    ``leader`` (B, T, 262): person 1 as the pipeline decodes them (for a re-rolled person 1,
    person 2), whose pace the rows that travel with them keep (``sflow.warm_together``), on
    their first pass's side (played at it with ``sflow.warm_play``); ``others`` (B, M, 2):
    where people 2..k - 1 start (``sflow.warm_apart``), whose spots and sides the row's
    reaction keeps off; ``bodies`` (B, M, T, 22, 3): the same people's joints, with
    ``sflow.warm_clear`` (:func:`beyond`)."""
    cfg = pipe.config.sflow
    if cfg.warm_proposal == "retrieved":
        if pipe.reactions is None:
            raise UMFError(
                f"the model {pipe.name} has sflow.warm_proposal 'retrieved' but no "
                f"{REACTIONS} (umf train reactions --model DIR --corpus CORPUS)"
            )
        unit = torch.nn.functional.normalize
        prompt = unit(text.pooled.float(), dim=-1)
        side = None if mirror is None else unit(mirror.pooled.float(), dim=-1)
        fps = pipe.config.fps
        own_pace = floor_velocity(decoded, fps) if cfg.warm_pace > 0 else None
        together = together_rows(pipe, decoded, leader)  # keep person 1's pace, not theirs
        velocity = own_pace
        if together is not None:
            velocity = torch.where(together[:, None], floor_velocity(leader, fps), own_pace)
        # the first pass's side, also where the prompt names one: the S-Flow reads a named
        # side since 20261208, more surely than warm_side's caption shortlist, which also
        # holds reactions whose captions name none (results/umf-small-bandai-20261211)
        stand = None if together is None else start_side(decoded) * together
        extend = None  # sflow.warm_extend: walkers of a single file, retrieved on its side
        if ends is not None and together is not None:
            extend = together & torch.isfinite(ends).all(dim=-1)
            x = torch.nan_to_num(ends[:, 0])
            stand = torch.where(extend, torch.sign(x) * (x.abs() > SIDE_MARGIN), stand)
        bank, frames = pipe.reactions, decoded.shape[1]
        # person k >= 3 keeps off people 2..k - 1: one travelling with person 1 is moved
        # beyond them below (:func:`beyond`), everybody else retrieved away from them
        avoid = others
        if others is not None and together is not None:
            avoid = torch.where(together[:, None, None], others.new_tensor(float("nan")), others)
        length, idx, fits = bank.pick(first, frames, cfg.warm_neighbours, generator,
                                      pipe.sflow.latent_norm.normalize, prompt,
                                      cfg.warm_shortlist, velocity, cfg.warm_pace,
                                      side, stand, avoid, cfg.warm_margin)  # fmt: skip
        z, waits = bank.latents[length].to(first)[idx], None
        if together is not None and length in bank.velocities:
            # beside a leader, a reaction nearer the leader's pace than the first pass fits,
            # within the tolerance or not: the first pass is the one that lags
            got = bank.velocities[length].to(velocity)[idx]
            nearer = (got - velocity).norm(dim=-1) < (own_pace - velocity).norm(dim=-1)
            fits = fits | (together & nearer)
        carried = None  # sflow.warm_follow: (rows, their latents) carried along person 1
        if together is not None and (cfg.warm_play or others is not None) and together.any():
            rows = together.nonzero().flatten()
            reaction = pipe.decode(z[rows], frames, reaction=True)
            changed = torch.zeros(len(rows), dtype=torch.bool, device=rows.device)
            played = None
            if cfg.warm_play:  # at person 1's pace, whatever the reaction's own: it fits
                own = floor_velocity(reaction, fps).norm(dim=-1).clamp_min(MOVING)
                played = play_at(reaction, velocity[rows].norm(dim=-1) / own)
                reaction = clear_of(played, leader[rows])  # level partners touched
                fits, changed = fits | together, ~changed
            reaction, moved = _placed(reaction, rows, ends, extend, others, bodies, cfg.warm_clear)
            changed = changed | moved
            if bool(changed.any()):
                z = z.clone()
                z[rows[changed]] = pipe._encode(reaction[changed]).to(z)
            if cfg.warm_follow is not None and played is not None:  # where person 1 turns
                turns = turning(leader[rows], cfg.warm_follow)
                if bool(turns.any()):
                    sub = rows[turns]
                    along = follow_leader(_placed(played[turns], sub, ends, extend)[0],
                                          leader[sub])  # fmt: skip
                    along = _placed(clear_of(along, leader[sub]), sub, ends, extend, others,
                                    bodies, cfg.warm_clear, file=False)[0]  # fmt: skip
                    carried = (sub, pipe._encode(along).to(z))
        if answers_first and bank.lags and cfg.warm_timing > 0:
            z, lag, stored = answers(bank, first, frames, z, cfg, generator,
                                     pipe.sflow.latent_norm.normalize, prompt,
                                     others)  # fmt: skip
            waits = (lag, stored)
        if carried is not None and waits is not None:  # an answer keeps its own reaction
            keep = (waits[0][carried[0]] <= 0).to(carried[0].device)
            carried = (carried[0][keep], carried[1][keep]) if bool(keep.any()) else None
        if carried is not None:  # proposed carried; the straight one kept to fall back on
            sub, along = carried
            carried, z = (sub, z[sub]), z.clone()
            z[sub] = along
        return z, 0, fits, waits, carried
    z, nfe = pflow_proposal(pipe, decoded, text, uncond, generator, guidance, own)
    ones = torch.ones(first.shape[0], dtype=torch.bool, device=first.device)
    return z, nfe, ones, None, None


def _placed(reaction: Tensor, rows: Tensor, ends: Tensor | None, extend: Tensor | None,
            others: Tensor | None = None, bodies: Tensor | None = None, clear: float = 0.0,
            file: bool = True) -> tuple[Tensor, Tensor]:  # fmt: skip
    """Reactions (R, T, 262) of the batch's ``rows`` moved to a single file's next place
    (``ends``, where ``extend``; not with ``file`` False: they are there already) and, with
    ``others``, beyond people 2..k - 1 (:func:`umf.clearance.beyond`; a file's walker is off
    their spots already), and (R,) which of them moved."""
    moved = torch.zeros(len(rows), dtype=torch.bool, device=reaction.device)
    go = None
    if extend is not None and bool(extend[rows].any()):
        go = extend[rows]
        if file:
            shift = torch.nan_to_num(ends[rows] - floor_start(reaction)) * go[:, None]
            reaction = place_features(reaction, 0.0, shift[:, 0], shift[:, 1])
            moved = go.clone()
    if others is not None:  # on someone's spot (or body): beyond them
        off = beyond(reaction, others[rows], None if bodies is None else bodies[rows], clear)
        if go is not None:
            off = torch.where(go[:, None, None], reaction, off)
        moved = moved | (off != reaction).any(dim=2).any(dim=1)
        reaction = off
    return reaction, moved


def answers(bank: Any, first: Tensor, frames: int, z: Tensor, cfg: Any, generator: Any,
            scale: Any, prompt: Tensor,
            others: Tensor | None = None) -> tuple[Tensor, Tensor, list[int]]:  # fmt: skip
    """The retrieved reactions ``z`` (B, p, r) with their waits (B,), for a warm start that
    retimes answers (``sflow.warm_timing`` w > 0). A row answers when the reactions of its
    prompt's nearest caption waited a median of at least w frames
    (:meth:`ReactionBank.caption_waits`), read at the stored length nearest ``frames``
    among those holding that caption (:meth:`ReactionBank.caption_length`: a 10-second
    spar asks the bank at 300 frames, which only carried-on walks, runs and real takes
    fill, and finds its answers at 285). Its reaction is then retrieved among that
    caption's (nearest the first pass, as always) with its own wait; every other row keeps
    ``z`` and waits 0. Also the stored length each row's reaction is of, to decode it at.
    Answers are gestures in place: neither ``sflow.warm_pace`` nor ``warm_side`` narrows
    them."""
    z, waits = z.clone(), torch.zeros(len(z), device=z.device)
    where = bank.caption_length(frames, prompt)
    stored = [bank.bucket(frames)] * len(z)
    for i, length in enumerate(where):
        found = bank.caption_waits(length, prompt[i : i + 1])
        if found is None or not float(found[0][0]) >= cfg.warm_timing:  # NaN: no caption
            continue
        gen = generator[i] if isinstance(generator, list | tuple) else generator
        _, idx, _ = bank.pick(first[i : i + 1], length, cfg.warm_neighbours, gen, scale,
                              prompt[i : i + 1], int(found[1][0]),
                              avoid=None if others is None else others[i : i + 1])  # fmt: skip
        z[i] = bank.latents[length].to(z)[idx[0]]
        waits[i], stored[i] = bank.lag(length, idx)[0], length
    return z, waits, stored


def pflow_proposal(
    pipe: Any,
    decoded: Tensor,
    text: Any,
    uncond: Any,
    generator: Any,
    guidance: float | None,
    own: dict[str, Any],
    dataset: int = MULTI_PERSON,
) -> tuple[Tensor, int]:
    """The P-Flow's motion for the prompt ``text`` and ``own`` (the person's own prompt,
    composed as ``pflow.person_composition`` says) with the P-Flow's ``dataset`` token,
    moved rigidly on the floor onto where each row of ``decoded`` (B, T, 262) starts: its
    latent (B, p, r) and the NFE."""
    z, nfe = pipe.pflow.sample(
        text,
        uncond,
        dataset=torch.full((decoded.shape[0],), dataset, dtype=torch.long, device=pipe.device),
        steps=pipe.config.pflow.steps,
        guidance=FROM_CONFIG if guidance is None else guidance,
        generator=generator,
        **own,
    )
    return pipe._encode(move_onto(pipe.decode(z, decoded.shape[1]), decoded)), nfe


def mirror_text(pipe: Any, words: list[str]) -> Any:
    """With ``sflow.warm_side``, the prompts (as the text encoder reads them) with their side
    words swapped (:func:`umf.text.mirror_caption`), encoded, for a retrieval on the side
    each names; None when off or when no prompt names a side. The S-Flow does not learn
    a named side from its captions (results/side-named-20261204); real reactions whose
    captions name it stand there."""
    if not (pipe.config.sflow.warm_side and pipe.config.sflow.warm_start):
        return None
    mirrored = [mirror_caption(w) for w in words]
    return None if mirrored == list(words) else pipe.text_encoder.encode(mirrored).to(pipe.device)


def onsets(features: Tensor) -> list[int]:
    """Each row's action onset (frame) in features (B, T, 262), as the relation checks read
    it (:func:`umf.data.relations.action_onset`, averaged over ``ONSET_SMOOTHING``)."""
    joints = features_to_joints(features.detach().float()).cpu().numpy()
    return [action_onset(j, smooth=ONSET_SMOOTHING) for j in joints]


# frames (0.5 s) an answer keeps before the scene ends, however long its real one waited
ANSWER_TAIL = 15


def retime(reaction: Tensor, leader: Tensor, lag: Tensor, passes: int = 2) -> Tensor:
    """Each row of ``reaction`` (B, T, 262) moved in time
    (:func:`umf.representation.shift_in_time`) so that its action starts ``lag`` (B,) frames
    after that of the same row of ``leader`` (B, T, 262), as the checks read onsets, but at
    the latest ``ANSWER_TAIL`` frames before the end (a late leader must not push the answer
    out of the scene). The reading moves a little with the frames held and cut, so the
    shift is corrected on the moved motion (``passes`` readings in all)."""
    last = reaction.shape[1] - ANSWER_TAIL
    want = [min(o + round(float(x)), last) for o, x in zip(onsets(leader), lag, strict=True)]
    shift = [0] * reaction.shape[0]
    out = reaction
    for _ in range(passes):
        shift = [s + w - o for s, w, o in zip(shift, want, onsets(out), strict=True)]
        out = torch.stack([shift_in_time(r, s) for r, s in zip(reaction, shift, strict=True)])
    return out


def timed_proposal(pipe: Any, guess: Tensor, prev: Tensor,
                   timing: tuple[Tensor, list[int]] | None, frames: int,
                   leader: Tensor | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
    """With ``sflow.warm_timing`` w > 0, the rows of ``guess`` (B, p, r) that :func:`answers`
    found an answer for (a wait of at least w frames in ``timing``) decoded at the length
    they were stored at, carried on or cut to ``frames``
    (:func:`umf.representation.hold_to_length`), moved in time (:func:`retime`) to start as
    long after the generated person 1 (``prev[:, 0]``) as they did after their own, and
    re-encoded; the others as they were. Also (B,) which rows were moved: the second pass
    from them replaces the first pass whether it glides or not. The S-Flow's first pass
    answers a bow at the average delay it saw (module notes). ``leader`` (B, T, 262):
    ``prev[:, 0]`` already decoded, if it was."""
    answer = torch.zeros(guess.shape[0], dtype=torch.bool, device=guess.device)
    if pipe.config.sflow.warm_timing <= 0 or timing is None:
        return guess, answer
    lag, stored = timing
    answer = lag >= pipe.config.sflow.warm_timing
    if not answer.any():
        return guess, answer
    rows = answer.nonzero().flatten()
    # person 1 as the pipeline decodes them (already decoded for sflow.warm_together)
    leader = pipe.decode(prev[rows, 0], frames) if leader is None else leader[rows]
    own = torch.stack([hold_to_length(pipe.decode(guess[i : i + 1], stored[i], reaction=True)[0],
                                      frames) for i in rows.tolist()])  # fmt: skip
    out = guess.clone()
    out[rows] = pipe._encode(retime(own, leader, lag[rows])).to(out)
    return out, answer


def warm_rows(decoded: Tensor, fits: Tensor, fps: float, glide: float) -> Tensor:
    """(B,) which first passes (``decoded`` (B, T, 262)) the second pass replaces: those the
    proposal ``fits``, and with ``glide`` > 0 (``sflow.warm_glide``) only those that glide
    (:func:`glide_score` above it)."""
    return fits & (glide_score(decoded, fps) > glide) if glide > 0 else fits


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
    mirror: Any = None,
    answers_first: bool = True,
    last: bool = True,
) -> tuple[Tensor, int]:
    """The next person's latent (B, p, r) and the NFE, as the pipeline and re-rolls sample
    people 2..N: the S-Flow's pass and, with ``sflow.warm_start``, the pass again from its
    proposal for the rows :func:`warm_rows` takes and the answers :func:`timed_proposal`
    retimed (it runs for every row, so a row's draws never depend on its batch). ``own``:
    the person's own prompt (:func:`umf.person_prompts.person_text`); ``pflow_guidance``:
    the caller's guidance for a P-Flow proposal (None: its config's); ``mirror``:
    :func:`mirror_text` of the prompts; ``answers_first``: ``prev[:, 0]`` is person 1, whom
    an answer waits for (False for a re-rolled person 1: nobody to wait for); ``last``:
    the person comes after everyone in ``prev`` (False for a re-rolled person inside the
    scene, whom ``sflow.warm_extend`` must not send to the end of a file)."""
    kw = {"steps": steps, "guidance": guidance, "generator": generator, **own}
    w, nfe = pipe.sflow.sample(prev, mask, text, uncond, **kw)
    cfg = pipe.config.sflow
    if own and cfg.own_warm:  # told what to do: from the P-Flow's motion for it, every row
        decoded = pipe.decode(w, frames, reaction=True)
        guess, m = pflow_proposal(pipe, decoded, own["person_text"], uncond, generator,
                                  pflow_guidance, {}, dataset=SINGLE_PERSON)  # fmt: skip
        w, n = pipe.sflow.sample(prev, mask, text, uncond, warm=guess, warm_t=cfg.own_warm, **kw)
        return w, nfe + m + n
    if cfg.warm_start:
        decoded = pipe.decode(w, frames, reaction=True)  # once: proposal and glide read it
        # person 1 (for a re-rolled person 1, person 2: the one they keep pace with)
        leader = (pipe.decode(prev[:, 0], frames, reaction=not answers_first)
                  if cfg.warm_together > 0 else None)  # fmt: skip
        # for person k >= 3: where people 2..k - 1 start (sflow.warm_apart) and their joints
        # (sflow.warm_clear), and whether the first pass touches anyone, person 1 too
        others = bodies = touching = ends = None
        if cfg.warm_apart and prev.shape[1] > 1:
            b, n = prev.shape[:2]
            there = pipe.decode(prev[:, 1:].flatten(0, 1), frames, reaction=True)
            others = floor_start(there).reshape(b, n - 1, 2)
            if cfg.warm_extend and last and leader is not None:  # person 2 began a file?
                second = there.reshape(b, n - 1, frames, -1)[:, 0]
                fps = pipe.config.fps
                began = travels_with(floor_velocity(second, fps), floor_velocity(leader, fps),
                                     cfg.warm_together)  # fmt: skip
                ends = formation_end(torch.cat([floor_start(leader)[:, None], others], 1), began)
            if cfg.warm_clear > 0:
                bodies = features_to_joints(there).reshape(b, n - 1, frames, 22, 3)
                first = leader if leader is not None else pipe.decode(
                    prev[:, 0], frames, reaction=not answers_first)  # fmt: skip
                everyone = torch.cat([features_to_joints(first)[:, None], bodies], dim=1)
                touching = touches(decoded, everyone, cfg.warm_clear)
        guess, m, fits, lag, straight = proposal(pipe, w, decoded, text, uncond, generator,
                                                 pflow_guidance, own, mirror=mirror,
                                                 answers_first=answers_first, leader=leader,
                                                 others=others, bodies=bodies,
                                                 ends=ends)  # fmt: skip
        guess, answer = timed_proposal(pipe, guess, prev, lag, frames, leader)
        turned = torch.zeros_like(answer)
        together = together_rows(pipe, decoded, leader) if others is not None else None
        if others is not None:  # people not travelling with person 1 turn to a free bearing
            free = ~together if together is not None else torch.ones_like(turned)
            if touching is not None:  # on someone's body, no real reaction at its pace: itself
                itself = free & ~fits & ~answer & touching
                guess = torch.where(itself[:, None, None], w, guess)
            rows = free.nonzero().flatten()
            if len(rows):
                seen = pipe.decode(guess[rows], frames, reaction=True)
                moved, hit = turned_free(seen, others[rows], bodies=None if bodies is None
                                         else bodies[rows], body_clear=cfg.warm_clear)  # fmt: skip
                if bool(hit.any()):
                    guess, turned = guess.clone(), turned.clone()
                    guess[rows[hit]] = pipe._encode(moved[hit]).to(guess)
                    turned[rows[hit]] = True
        # person k >= 3: a context of 2+ people, which the S-Flow never trained on, pulls
        # the second pass back to where a partner of person 1 stands (sflow.warm_start_group)
        later = cfg.warm_start_group if prev.shape[1] > 1 and cfg.warm_start_group else None
        twins = None if straight is None else twin(generator)  # the same draws, again
        again, n = pipe.sflow.sample(prev, mask, text, uncond, warm=guess, warm_t=later, **kw)
        nfe += m + n
        take = warm_rows(decoded, fits, pipe.config.fps, cfg.warm_glide) | answer | turned
        if others is not None:  # a first pass on someone's spot is sampled again, gliding or not
            take = take | (fits & crowded(decoded, others))
        if touching is not None:  # a first pass on someone's body at any frame, fitting or not
            take = take | touching
        if ends is not None and together is not None:  # a file's walker takes its place there
            take = take | (together & torch.isfinite(ends).all(dim=-1))
        if straight is not None and leader is not None:  # carried, but onto someone?
            again, n = fall_back(pipe, again, straight, take & ~answer, prev, mask, text,
                                 uncond, frames, leader, bodies, {**kw, "generator": twins},
                                 later)  # fmt: skip
            nfe += n
        w = torch.where(take[:, None, None], again, w)
    return w, nfe
