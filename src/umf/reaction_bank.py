"""Real reactions a model was trained on, for the warm start of people 2..N.

The S-Flow's own first pass knows a person's role and place (who walks over, who steps
back, on which side) but glides; a real reaction strides. ``sflow.warm_proposal =
"retrieved"`` (:mod:`umf.warm_start`) warm-starts each added person from one of the real
reactions of the training split nearest to the first pass, in the S-Flow's latent space,
so the second pass keeps the role and gains the stride.

A model directory carries them in ``reactions.safetensors``: for each length of a set
(``frames_30``, ``frames_45`` ... feature frames), the VAE's posterior means (N, p, r) of
people 2..N of the training scenes, cropped to that length in person 1's frame (the crop
the S-Flow trains on), with their scene captions' embeddings (``text_*``) and their
pelvis's mean floor velocity in person 1's frame, (x, z) in m/s (``velocity_*``), and, for
a person whose relation answers person 1 (a bow back, a response), how many frames after
person 1's their action starts in the whole scene (``lag_*``,
:func:`umf.data.relations.action_onset`; 0 for everybody else), and where the person's
pelvis starts on the floor, (x, z) in m in person 1's frame (``start_*``). Beside them, the
real takes whose people touch (a salsa couple) are kept whole, both people of a crop every
second (``takes_*``, (N, 2, p, r)), with the rows of their take's captions (``take_caption_*``,
(N, C), -1 where a take has fewer): ``sflow.warm_take`` starts such a couple from one of
them. They are derived from the training data and carry its licence.
``umf train reactions`` (:func:`umf.train.reactions.build_reaction_bank`) writes them.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from umf.data.relations import SIDE_MARGIN
from umf.errors import UMFError
from umf.flows.noise import Generators, randn
from umf.io import save_tensors_atomic

REACTIONS = "reactions.safetensors"
PREFIX = "frames_"
TEXT = "text_"  # one embedding per reaction (banks written before the shared table)
CAPTIONS = "captions"  # the distinct caption embeddings (U, D) ...
CAPTION = "caption_"  # ... and each reaction's row of them (N,), per length
# the slowest speed (m/s) a pace tolerance is a share of: a person barely travelling would
# otherwise match no reaction but its own standstill
PACE_FLOOR = 0.5
VELOCITY = "velocity_"
LAG = "lag_"
START = "start_"
TAKE = "takes_"  # both people of a crop of a touching real take (N, 2, p, r) ...
TAKE_CAPTION = "take_caption_"  # ... and its take's caption rows (N, C), -1: none
TAKE_SOURCE = "take_source_"  # ... and where it was cut: (N, 2) its take's row of the file's
TAKE_NAMES = "take_names"  # metadata, a JSON list of the takes' clip ids, and its first frame
# how much nearer a caption may be to a prompt's mirror image than to the prompt and still be
# on its side: equal within float error (captions naming no side are as near both)
SAME_SIDE = 1e-5
# m between two people's first-frame pelvises under which a reaction starts where someone
# already stands: real partners side by side start 0.7-1.1 m from person 1, so two of them
# on one side start closer than this (sflow.warm_apart)
SPOT = 0.8

Tensor = torch.Tensor


def _per_length(raw: dict[str, Tensor], prefix: str) -> dict[int, Tensor]:
    """The tensors of a bank file named ``prefix`` and a length, by length, in float."""
    return {int(k.removeprefix(prefix)): v.float() for k, v in raw.items() if k.startswith(prefix)}


def _narrowed(keep: Tensor, allowed: Tensor | None) -> Tensor:
    """``allowed`` (B, N) (None: everything) and ``keep`` (B, N), except for rows where
    nothing allowed is kept: those keep what they were allowed."""
    rest = torch.ones_like(keep) if allowed is None else allowed
    keep = keep & rest
    return torch.where(keep.any(dim=1, keepdim=True), keep, rest)


def _embedded(table: Tensor | None, rows: Tensor, name: str, padded: bool) -> Tensor:
    """The caption embeddings that rows of the file's caption ``table`` (U, D) stand for:
    ``rows`` (N,) for reactions, or (N, C) padded with -1 for takes (``padded``; NaN rows
    there). Raises ValueError where they index no table."""
    integer = rows.dtype in (torch.int32, torch.int64) and rows.ndim == (2 if padded else 1)
    low = -1 if padded else 0
    if table is None or table.ndim != 2 or not integer or bool((rows < low).any()) or (
            len(rows) and rows.max() >= len(table)):  # fmt: skip
        raise ValueError(f"{name} indexes no caption table")
    return table[rows.clamp_min(0).long()].float().masked_fill((rows < 0)[..., None], torch.nan)


def nearest_length(lengths: Iterable[int], frames: int) -> int:
    """The one of ``lengths`` nearest to ``frames`` (the shorter on a tie)."""
    return min(lengths, key=lambda k: (abs(k - frames), k))


@dataclass
class ReactionBank:
    """Real reactions per length: ``latents[frames]`` (N, p, r) on the VAE's scale."""

    latents: dict[int, Tensor]
    # per length, each reaction's scene caption as a unit sentence embedding (N, D) in the
    # model's text encoder (umf.coverage.embed), for a shortlist by the prompt; may be empty
    texts: dict[int, Tensor] = field(default_factory=dict)
    # per length, each reaction's pelvis mean floor velocity (N, 2) in m/s, person 1's frame
    # (umf.warm_start.floor_velocity); may be empty
    velocities: dict[int, Tensor] = field(default_factory=dict)
    # per length, the frames (N,) from person 1's action onset to an answer's in its scene
    # (umf.data.relations.action_onset), for an answer retimed to a generated person 1
    # (sflow.warm_timing); may be empty
    lags: dict[int, Tensor] = field(default_factory=dict)
    # per length, each reaction's first-frame pelvis on the floor (N, 2), x and z in m in
    # person 1's frame (+x: person 1's left), for a reaction on a given side; may be empty
    starts: dict[int, Tensor] = field(default_factory=dict)
    # per length, crops of the real takes whose people touch, both people (N, 2, p, r) on
    # the VAE's scale, person 1's frame, and their take's captions as unit sentence
    # embeddings (N, C, D), NaN rows where a take has fewer than C; may be empty
    takes: dict[int, Tensor] = field(default_factory=dict)
    take_texts: dict[int, Tensor] = field(default_factory=dict)
    # where each crop was cut, (N, 2) ints: its take's row of ``take_names`` (the clip ids)
    # and its first feature frame in the take; may be empty (a bank written before them)
    take_sources: dict[int, Tensor] = field(default_factory=dict)
    take_names: list[str] = field(default_factory=list)

    def lengths(self) -> list[int]:
        return sorted(self.latents)

    def save(self, model_dir: str | Path) -> Path:
        """Write ``reactions.safetensors`` into a model directory atomically (fp16). A scene's
        caption is shared by its people and its crops, so the caption embeddings are stored
        once each (``captions``) with each reaction's row (``caption_*``): the bundled
        model's bank holds 16,113 reactions of about 60 distinct captions per length."""
        path = Path(model_dir) / REACTIONS
        tensors = {f"{PREFIX}{k}": v for k, v in self.latents.items()}
        tensors |= {f"{VELOCITY}{k}": v for k, v in self.velocities.items()}
        tensors |= {f"{LAG}{k}": v for k, v in self.lags.items()}  # whole frames: exact in fp16
        tensors |= {f"{START}{k}": v for k, v in self.starts.items()}
        tensors = {k: v.to(torch.float16) for k, v in tensors.items()}
        tensors |= {f"{TAKE}{k}": v.to(torch.float16) for k, v in self.takes.items()}
        tensors |= {f"{TAKE_SOURCE}{k}": v.to(torch.int32) for k, v in self.take_sources.items()}
        metadata = {TAKE_NAMES: json.dumps(self.take_names)} if self.take_names else None
        if self.texts or self.take_texts:  # one table for the reactions' and takes' captions
            parts = [(CAPTION, k, self.texts[k], None) for k in sorted(self.texts)]
            for k in sorted(self.take_texts):
                e = self.take_texts[k]
                have = ~e.isnan().any(-1)  # (N, C)
                parts.append((TAKE_CAPTION, k, e[have], have))
            every = torch.cat([e.to(torch.float16) for _, _, e, _ in parts])
            table, rows = torch.unique(every, dim=0, return_inverse=True)
            tensors[CAPTIONS] = table
            for (name, k, _, have), part in zip(parts, rows.split([len(e) for _, _, e, _ in parts]),
                                                strict=True):  # fmt: skip
                if have is not None:  # a take's captions: its rows, -1 past the last
                    part = torch.full(have.shape, -1, dtype=part.dtype).masked_scatter(have, part)
                tensors[f"{name}{k}"] = part.to(torch.int32)
        save_tensors_atomic({k: v.contiguous() for k, v in tensors.items()}, path, metadata)
        path.chmod(0o644)
        return path

    @classmethod
    def load(cls, model_dir: str | Path, shape: Sequence[int] | None = None) -> ReactionBank | None:
        """The model's reactions, or None when it has none; ``shape`` (p, r) checks them."""
        from safetensors import SafetensorError, safe_open
        from safetensors.torch import load_file

        path = Path(model_dir) / REACTIONS
        if not path.exists():
            return None
        try:
            raw = load_file(str(path))
            with safe_open(str(path), "pt") as f:
                names = json.loads((f.metadata() or {}).get(TAKE_NAMES, "[]"))
            if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                raise ValueError("take names are not a list of strings")
            sources = {int(k.removeprefix(TAKE_SOURCE)): v for k, v in raw.items()
                       if k.startswith(TAKE_SOURCE)}  # fmt: skip
            latents, texts = _per_length(raw, PREFIX), _per_length(raw, TEXT)
            table = raw.get(CAPTIONS)
            for k, rows in raw.items():
                if k.startswith(CAPTION) and k != CAPTIONS:
                    texts[int(k.removeprefix(CAPTION))] = _embedded(table, rows, k, padded=False)
            velocities, lags = _per_length(raw, VELOCITY), _per_length(raw, LAG)
            starts, takes = _per_length(raw, START), _per_length(raw, TAKE)
            take_texts = {int(k.removeprefix(TAKE_CAPTION)): _embedded(table, rows, k, padded=True)
                          for k, rows in raw.items() if k.startswith(TAKE_CAPTION)}  # fmt: skip
        except (OSError, ValueError, RuntimeError, IndexError, SafetensorError) as exc:
            raise UMFError(f"{path}: corrupt reaction bank ({type(exc).__name__})") from None
        for frames, z in latents.items():
            fits = z.ndim == 3 and len(z) and (shape is None or z.shape[1:] == tuple(shape))
            if not fits or not torch.isfinite(z).all():
                raise UMFError(f"{path}: reactions of {frames} frames do not fit the model")
        for frames, e in texts.items():
            z = latents.get(frames)
            if z is None or e.ndim != 2 or len(e) != len(z) or not torch.isfinite(e).all():
                raise UMFError(f"{path}: captions of {frames} frames do not match its reactions")
        for name, table, row in (("velocities", velocities, (2,)), ("starts", starts, (2,)),
                                 ("lags", lags, ())):  # fmt: skip
            for frames, v in table.items():
                z = latents.get(frames)
                if z is None or v.shape != (len(z), *row) or not torch.isfinite(v).all():
                    raise UMFError(f"{path}: {name} of {frames} frames do not match its "
                                   "reactions")  # fmt: skip
        for frames, z in takes.items():
            e = take_texts.get(frames)
            fits = (
                z.ndim == 4 and z.shape[1] == 2 and (shape is None or z.shape[2:] == tuple(shape))
            )
            if not fits or not torch.isfinite(z).all() or e is None or len(e) != len(z):
                raise UMFError(f"{path}: takes of {frames} frames do not fit the model")
            where = sources.get(frames)
            if where is not None and (where.shape != (len(z), 2) or where.is_floating_point()
                                      or bool((where[:, 0] < 0).any())
                                      or bool((where[:, 0] >= len(names)).any())):  # fmt: skip
                raise UMFError(f"{path}: the sources of the takes of {frames} frames are corrupt")
        if not latents:
            raise UMFError(f"{path}: an empty reaction bank")
        return cls(latents, texts, velocities, lags, starts, takes, take_texts,
                   {k: v.long() for k, v in sources.items() if k in takes}, names)  # fmt: skip

    def take_source(self, length: int, idx: Tensor) -> list[dict[str, Any] | None]:
        """Where the crops ``idx`` (R,) of ``length`` were cut: per crop ``{"take": clip id,
        "start_frame": its first feature frame in the take, "frames": length}``; None for a
        bank written before the sources."""
        where = self.take_sources.get(length)
        if where is None:
            return [None] * len(idx)
        rows = where[idx.cpu().long()].tolist()
        return [{"take": self.take_names[r], "start_frame": int(f), "frames": int(length)}
                for r, f in rows]  # fmt: skip

    def pick_take(self, frames: int, prompt: Tensor,
                  generator: Generators = None) -> tuple[int, Tensor, Tensor] | None:  # fmt: skip
        """For each row of ``prompt`` (B, D) unit sentence embeddings, a crop of a touching
        real take: the stored length nearest ``frames`` it is of, its index (B,) there, drawn
        uniformly with row i's generator among the crops of the takes whose captions come
        nearest the prompt (ties within ``SAME_SIDE``), and (B,) whether those are the takes
        nearest the prompt at any length (a take too short for ``frames``, such as a
        handshake asked for 4 s, leaves a longer one nearest there: not its own). None for a
        bank without takes."""
        if not self.takes:
            return None
        best = {}  # per length, each row's crops and how near their captions come
        for k, e in self.take_texts.items():
            e = e.to(prompt.device)  # (N, C, D)
            sims = torch.einsum("bd,ncd->bnc", prompt.float(), e.nan_to_num(0.0))
            best[k] = sims.masked_fill(e.isnan().any(-1)[None], -torch.inf).amax(-1)  # (B, N)
        length = nearest_length(self.takes, frames)
        sims = best[length]
        top = sims.amax(dim=1)
        anywhere = torch.stack([s.amax(dim=1) for s in best.values()], dim=1).amax(dim=1)
        near = sims >= top[:, None] - SAME_SIDE
        score = randn(tuple(sims.shape), generator, device=prompt.device)
        idx = score.masked_fill(~near, -torch.inf).argmax(dim=1)
        return length, idx, top >= anywhere - SAME_SIDE

    def bucket(self, frames: int) -> int:
        """The stored length nearest to ``frames`` (the shorter on a tie)."""
        return nearest_length(self.latents, frames)

    def _gap(self, length: int, velocity: Tensor) -> Tensor:
        """(B, N) distances between each row's velocity (B, 2) and the stored ones."""
        return torch.cdist(velocity, self.velocities[length].to(velocity))

    def _within(self, length: int, velocity: Tensor, pace: float) -> Tensor:
        """(B, N) the reactions within ``pace`` x each row's speed (at least ``PACE_FLOOR``)
        of its velocity."""
        tolerance = pace * velocity.norm(dim=-1, keepdim=True).clamp_min(PACE_FLOOR)
        return self._gap(length, velocity) <= tolerance

    def _shortlisted(self, length: int, prompt: Tensor | None, shortlist: int,
                     like: Tensor, mirror: Tensor | None = None,
                     margin: float = 0.0) -> Tensor | None:  # fmt: skip
        """(B, N) the ``shortlist`` reactions whose captions are nearest each row's prompt
        (B, D), or None where every reaction competes (no prompt, no shortlist, or a bank
        without captions). ``mirror`` (B, D): each prompt with its side words swapped; then
        only captions at least as near the prompt as its mirror image compete. ``margin``
        > 0 (``sflow.warm_margin``): a row whose prompt is farther than ``margin`` (cosine)
        from every caption (a group's caption: the bank holds pairs; a paraphrase) keeps only
        the captions within ``margin`` of its nearest one, which is taken before the mirror
        test. Without it, "three people walk in single file." shortlisted 40 single-file
        reactions and 24 side-by-side ones to fill its list, and the first pass's side then
        chose those (results/umf-small-bandai-20261214). A prompt worded like a caption keeps
        the whole list: narrowed, "Two people run side by side." lost partners at its pace.
        Few may be left: "A person calls and four people walk over to them." keeps 3."""
        if prompt is None or shortlist <= 0 or length not in self.texts:
            return None
        captions = self.texts[length].to(like)
        sims = prompt.to(like) @ captions.T  # (B, N)
        if margin > 0:
            best = sims.max(dim=1, keepdim=True).values
            far = best < 1.0 - margin  # worded like no caption: a group's, a paraphrase
            sims = sims.masked_fill(far & (sims < best - margin), -torch.inf)
        if mirror is not None:  # the other side's captions are nearer the mirror image
            same = sims >= mirror.to(like) @ captions.T - SAME_SIDE
            same[~same.any(dim=1)] = True  # no caption on a row's side: every caption
            sims = sims.masked_fill(~same, -torch.inf)
        keep = sims.topk(min(shortlist, sims.shape[1]), dim=1).indices
        chosen = torch.zeros(sims.shape, dtype=torch.bool, device=sims.device)
        return chosen.scatter(1, keep, True) & torch.isfinite(sims)

    def _free(self, length: int, avoid: Tensor, allowed: Tensor | None) -> Tensor:
        """``allowed`` (B, N) (None: every reaction) narrowed to the reactions that start at
        least ``SPOT`` from every point of ``avoid`` (B, M, 2); a row with none keeps what it
        had."""
        start = self.starts[length].to(avoid)  # (N, 2)
        gap = torch.cdist(avoid, start[None].expand(len(avoid), -1, -1))  # (B, M, N)
        return _narrowed(((gap >= SPOT) | gap.isnan()).all(dim=1), allowed)  # NaN: nobody

    def _on_side(self, length: int, stand: Tensor, allowed: Tensor | None) -> Tensor:
        """``allowed`` (B, N) (None: every reaction) narrowed, for the rows whose ``stand``
        (B,) is +1 or -1, to the reactions starting more than ``SIDE_MARGIN`` to that side of
        person 1; a row with none there keeps what it had."""
        x = self.starts[length][:, 0].to(stand)  # (N,)
        return _narrowed((stand[:, None] == 0) | (x[None] * stand[:, None] > SIDE_MARGIN), allowed)

    def lag(self, length: int, idx: Tensor) -> Tensor | None:
        """(B,) the lags (frames) of the reactions ``idx`` stored at ``length`` (as
        :meth:`pick` returns them); None for a bank without lags (written before them)."""
        return self.lags[length][idx.cpu()] if length in self.lags else None

    def caption_waits(self, frames: int, prompt: Tensor) -> tuple[Tensor, Tensor] | None:
        """Per row of ``prompt`` (B, D) unit embeddings, at the stored length nearest
        ``frames``: the median lag (frames) of the reactions whose caption is the nearest
        to the prompt (ties within ``SAME_SIDE``), and how many they are. How long people
        asked what the prompt asks waited for person 1 in the training scenes. None for a
        bank without lags or captions."""
        length = self.bucket(frames)
        if length not in self.lags or length not in self.texts:
            return None
        sims = prompt.float() @ self.texts[length].to(prompt.device).T  # (B, N)
        group = sims >= sims.amax(dim=1, keepdim=True) - SAME_SIDE
        lags = self.lags[length].to(prompt.device)[None].expand(len(group), -1)
        median = lags.masked_fill(~group, torch.nan).nanmedian(dim=1).values
        return median, group.sum(dim=1)

    def caption_length(self, frames: int, prompt: Tensor) -> list[int]:
        """Per row of ``prompt`` (B, D) unit embeddings, the stored length nearest ``frames``
        (the shorter on a tie) among those whose captions come as near the prompt as any
        length's do: where the bank keeps reactions of what the prompt asks. A bank without
        captions: the length nearest ``frames`` for every row."""
        lengths = [k for k in self.lengths() if k in self.texts]
        if not lengths:
            return [self.bucket(frames)] * len(prompt)
        best = torch.stack([(prompt.float() @ self.texts[k].to(prompt.device).T).amax(dim=1)
                            for k in lengths], dim=1)  # fmt: skip  # (B, L)
        near = best >= best.amax(dim=1, keepdim=True) - SAME_SIDE
        return [nearest_length([k for k, ok in zip(lengths, row, strict=True) if ok], frames)
                for row in near.tolist()]  # fmt: skip

    def pick(
        self,
        query: Tensor,
        frames: int,
        neighbours: int,
        generator: Generators = None,
        scale: Callable[[Tensor], Tensor] = lambda z: z,
        prompt: Tensor | None = None,
        shortlist: int = 0,
        velocity: Tensor | None = None,
        pace: float = 0.0,
        mirror: Tensor | None = None,
        stand: Tensor | None = None,
        avoid: Tensor | None = None,
        margin: float = 0.0,
    ) -> tuple[int, Tensor, Tensor]:
        """For each row of ``query`` (B, p, r) a real reaction: the stored length it is of, its
        index (B,) there and (B,) whether the row had one at its pace. The reaction is one of the
        ``neighbours`` nearest (Euclidean after ``scale``, e.g. the S-Flow's latent
        normaliser) among those of the stored length nearest to ``frames``, drawn uniformly
        with row i's generator. ``prompt`` (B, D) unit sentence embeddings and ``shortlist``
        > 0: only among the ``shortlist`` reactions whose captions are nearest the prompt
        (a bank without captions ignores them). ``velocity`` (B, 2) m/s and ``pace`` > 0: only
        among those whose pelvis velocity is within ``pace`` x the row's speed (at least
        ``PACE_FLOOR``) of it (speed and direction in person 1's frame), and the
        ``neighbours`` nearest in velocity where fewer are (a bank without velocities ignores
        them). ``mirror`` (B, D): the prompts' mirror images (their side words swapped,
        :func:`umf.text.mirror_caption`), unit embeddings: the shortlist then holds only
        reactions whose captions are at least as near the prompt as its mirror image, so a
        prompt naming a side retrieves people on that side (a prompt naming none is its own
        mirror image: no change). ``stand`` (B,): +1 or -1 for a row whose reaction must
        start on person 1's left (+x) or right, 0 for any side (a bank without starts, or a
        row with no reaction on its side, ignores it). ``avoid`` (B, M, 2): where people
        already in each row's scene start on the floor (x, z in person 1's frame); only the
        reactions starting at least ``SPOT`` from all of them compete (a row with none keeps
        what it had; NaN points stand for nobody). ``margin`` > 0: a prompt farther than it
        from every caption shortlists only captions within it of its nearest one
        (``sflow.warm_margin``). Whether each row had one within its
        pace is all True without a pace, so a caller can keep what it had rather than take a
        reaction at the wrong pace."""
        length = self.bucket(frames)
        bank = self.latents[length].to(query)
        d = torch.cdist(scale(query).flatten(1), scale(bank).flatten(1))
        listed = self._shortlisted(length, prompt, shortlist, d, mirror, margin)
        allowed = listed
        if avoid is not None and avoid.shape[1] and length in self.starts:
            allowed = self._free(length, avoid.to(d), allowed)
        if stand is not None and length in self.starts:
            allowed = self._on_side(length, stand.to(d), allowed)
        if allowed is not None:
            d = d.masked_fill(~allowed, float("inf"))
        k = max(1, min(int(neighbours), bank.shape[0] if listed is None else shortlist,
                       bank.shape[0]))  # fmt: skip
        at_pace = torch.ones(query.shape[0], dtype=torch.bool, device=query.device)
        if velocity is not None and pace > 0 and length in self.velocities:
            velocity = velocity.to(d)
            gap, near = self._gap(length, velocity), self._within(length, velocity, pace)
            if allowed is not None:  # the shortlist's only
                gap, near = gap.masked_fill(~allowed, float("inf")), near & allowed
            at_pace = near.any(dim=1)
            near.scatter_(1, gap.topk(k, dim=1, largest=False).indices, True)
            d = d.masked_fill(~near, float("inf"))
        dist, idx = d.topk(k, dim=1, largest=False)  # (B, k), nearest first
        # the same k draws for every row; a row whose shortlist holds fewer than k draws
        # among its own (finite) ones, so no row's pick depends on the others in its batch
        score = randn((query.shape[0], k), generator, device=query.device)
        pick = score.masked_fill(~torch.isfinite(dist), -torch.inf).argmax(dim=1)
        return length, idx[torch.arange(query.shape[0], device=query.device), pick], at_pace
