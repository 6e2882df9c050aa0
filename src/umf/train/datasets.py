"""Torch datasets over a prepared corpus: random crops, placement, mirroring, padding.

Frames of reference (decided here, used by every stage):

* Every crop is re-canonicalised at its first frame: person 1's pelvis goes over the
  origin and person 1 faces +Z (:func:`canonicalize_features`). Heights are kept as the
  corpus floored them (lowest joint of the whole clip on y = 0): re-flooring each crop
  would lift a jump's take-off off the floor. P-Flow and S-Flow train on this frame.
* The VAE additionally sees ``random_placement``: a random yaw in [-pi, pi) and an XZ
  offset within ``placement_radius`` metres (:func:`place_features`), because it must
  encode person 2..N too, who start anywhere facing anywhere.
* Short clips: a single-person clip shorter than the shortest crop is served whole and
  then extended where that can be done truthfully (``hold_rest``, ``repeat_gait``,
  ``settle``: :mod:`umf.data.extension`), else as it is.
* Mirroring (p = 0.5) flips the motion left/right and swaps the side words of the caption
  (:func:`mirror_caption`); a canonical crop stays canonical when mirrored.

Every random choice of an item is drawn from a generator keyed by (seed, epoch, index),
so an item does not depend on worker processes or on what was loaded before it: a
resumed run sees exactly the data an uninterrupted run would have seen.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Hashable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from umf.config import MULTI_PERSON, SINGLE_PERSON, metadata_pairs
from umf.data.clip import MotionClip
from umf.data.corpus import Corpus
from umf.data.extension import (
    SETTLE,
    extend_person,
    extend_scene,
    extension_period,
    gait_period,
    scene_gait_periods,
)
from umf.data.scenes import build_scene, scene_features_of, scene_rotations
from umf.errors import UMFError
from umf.representation import (
    Normalizer,
    RigidTransform,
    assemble_features,
    canonical_transform,
    canonicalize_features,
    mirror_features,
    place_features,
)
from umf.text import mirror_caption, swap_words, word_pattern
from umf.train.batching import collate_scenes, collate_single

Tensor = torch.Tensor

# Chance that a single-person item carries an own prompt (one of its clip's wordings)
OWN_SINGLE = 0.5
PLACEMENT_RADIUS = 3.0  # metres: people of a scene stand within a few metres of each other

# Spellings the captions use one way and people write the other: the corpus says "walks
# backwards", a user types "walks backward", and the flows condition on token states, so
# the unseen spelling alone cost walking backward three quarters of its speed
# (results/finetunes-cpu-20261126/walk-back.md).
_SPELLINGS = {"backwards": "backward", "forwards": "forward", "towards": "toward"}
_SPELLINGS |= {v: k for k, v in _SPELLINGS.items()}


_SPELL_RE = word_pattern(_SPELLINGS)


# --------------------------------------------------------------------- pure functions
def respell_caption(text: str) -> str:
    """The other spelling of direction words: backwards <-> backward, forwards <-> forward,
    towards <-> toward (same meaning; training on both makes either prompt work)."""
    return swap_words(text, _SPELLINGS, _SPELL_RE)


def preferred_spellings(captions: Sequence[str]) -> tuple[str, ...]:
    """``"unseen=seen"`` for each direction word whose one spelling the captions never use
    and the other they do (``text.respell``: prompts are respelled before encoding, so a
    user's "walks backward" reads as the captions' "walks backwards")."""
    counts = Counter(w.lower() for c in captions for w in _SPELL_RE.findall(c))
    return tuple(sorted(f"{a}={b}" for a, b in _SPELLINGS.items()
                        if counts[a] == 0 and counts[b] > 0))  # fmt: skip


def own_caption(captions: Sequence[str], rng: np.random.Generator, present: float = 1.0) -> str:
    """A person's own caption (their per-person prompt in training): one of their clip's
    wordings with chance ``present``, else "" (no own prompt)."""
    if not captions or rng.random() >= present:
        return ""
    return captions[int(rng.integers(len(captions)))]


def crop_window(
    rng: np.random.Generator, total: int, min_frames: int, max_frames: int
) -> tuple[int, int]:
    """(start, length): length uniform in [min, max] capped by ``total``, start uniform."""
    hi = min(max_frames, total)
    lo = min(min_frames, hi)
    length = int(rng.integers(lo, hi + 1))
    return int(rng.integers(0, total - length + 1)), length


def item_rng(seed: int, epoch: int, index: int, stream: int = 0) -> np.random.Generator:
    """The generator of one item: a function of (seed, epoch, index) only; ``stream`` > 0
    gives the item an independent extra generator (draws that must not shift the others)."""
    return np.random.default_rng([seed % 2**63, epoch, index, *([stream] if stream else [])])


def _check_frames(min_frames: int, max_frames: int) -> None:
    if not 1 <= min_frames <= max_frames:
        raise UMFError(f"need 1 <= min_frames <= max_frames, got {min_frames}, {max_frames}")


def _clip_crop(
    clip: MotionClip,
    tf: RigidTransform,
    people: Sequence[int],
    start: int,
    length: int,
    period: int = 0,
):
    """Features (len(people), length, 262) of a crop, in the clip's floored frame; frames
    past the clip's end hold its last pose (``period`` 0), repeat its last ``period`` or,
    for :data:`SETTLE`, follow its end eased to a stop (:func:`extend_person`)."""
    if clip.rot6d is None:
        raise UMFError(f"{clip.id}: no rotations; load clips through a prepared corpus")
    stop = start + length + 1  # one more joint frame gives the last velocity
    out = []
    for p in people:
        joints, rot = extend_person(clip.joints[p], clip.rot6d[p], start, stop, period)
        joints = tf.apply(torch.from_numpy(np.ascontiguousarray(joints)))
        out.append(assemble_features(joints, torch.from_numpy(np.ascontiguousarray(rot))))
    return torch.stack(out)


def _finish(
    features: Tensor,
    normalizer: Normalizer | None,
    caption: str,
    rng: np.random.Generator,
    mirror: bool,
    respell: bool = False,
) -> tuple[Tensor, str, bool]:
    """Mirror with p = 0.5, respell the caption with p = 0.5 (drawn last, and only when
    asked, so neither shifts the other draws) and normalise."""
    mirrored = bool(mirror and rng.random() < 0.5)
    if mirrored:
        features = mirror_features(features)
        caption = mirror_caption(caption)
    if respell and rng.random() < 0.5:
        caption = respell_caption(caption)
    if normalizer is not None:
        features = normalizer.normalize(features)
    return features.float().contiguous(), caption, mirrored


class _EpochDataset(Dataset):
    """Map-style dataset whose random draws depend on (seed, epoch, index)."""

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """New random crops each epoch; called by the trainer before each pass."""
        self.epoch = int(epoch)

    def _rng(self, index: int) -> np.random.Generator:
        return item_rng(self.seed, self.epoch, index)


def label_repeats(labels: Sequence[Hashable | None], power: float) -> list[int]:
    """How often each item appears per epoch so that rare labels are seen more often.

    An item whose label has ``count`` items repeats round((most / count) ** power) times,
    ``most`` being the commonest label's count: power 0 leaves the data as it is, 1 gives
    every label the same share, 0.5 (the square root) moves each label's share from count
    towards sqrt(count). Unlabelled items (None: corpora without content labels) appear once
    and do not count towards ``most``. Why: the Bandai corpus has 348 training clips of
    raising both hands and 11 of walking backward, and a flow learns the rare ones late.
    """
    if not 0 <= power <= 1:
        raise ValueError(f"label balance power must be between 0 and 1, got {power}")
    counts = Counter(label for label in labels if label is not None)
    most = max(counts.values(), default=1)
    return [1 if label is None else max(1, round((most / counts[label]) ** power))
            for label in labels]  # fmt: skip


def check_labels(corpus: Corpus, labels: Sequence[str]) -> None:
    """Refuse content labels that no clip of the corpus (any split) has, listing those it
    has: a typo must not become an empty training set."""
    known = sorted({str(c.meta["content"]) for c in corpus.clips if c.meta.get("content")})
    unknown = [label for label in labels if label not in known]
    if unknown:
        listed = ", ".join(known) if known else "none: this corpus has no content labels"
        raise UMFError(f"unknown content label {unknown[0]!r} (known: {listed})")


def _with_labels(
    items: list[tuple[MotionClip, int, RigidTransform]],
    labels: Sequence[str],
    corpus: Corpus,
    split: str,
) -> list[tuple[MotionClip, int, RigidTransform]]:
    """The items whose clip has one of ``labels`` as its content label.

    Why: fine-tuning or probing a stage on one kind of motion (e.g. only waves) without
    preparing a corpus of its own. Labels the corpus lacks are refused, listing its labels;
    a split without clips of them is an error of its own (training needs validation too).
    """
    wanted = set(labels)
    kept = [item for item in items if str(item[0].meta.get("content")) in wanted]
    absent = wanted - {str(clip.meta.get("content")) for clip, _, _ in kept}
    if absent:  # not in this split: a typo, or a label only other splits have
        check_labels(corpus, [label for label in labels if label in absent])
    if not kept:
        raise UMFError(f"{corpus.root}: no clips labelled {', '.join(labels)} in split "
                       f"{split!r}; training needs some in train and in val")  # fmt: skip
    return kept


# --------------------------------------------------------------------- single person
class SingleMotionDataset(_EpochDataset):
    """One person's random crop per item, canonical at the crop start (+ optional placement).

    Items are the people of the split's clips: each single-person clip, and each person of
    a real multi-person clip (dataset token 1, with the clip's caption). ``normalizer=None``
    serves raw features (for inspection). ``balance`` > 0 repeats the items of rare content
    labels (:func:`label_repeats`); each repeat draws its own crop, mirror and caption.
    ``respell`` gives half the captions their other spelling (:func:`respell_caption`).
    ``labels``: only the people of clips with these content labels (all when empty).
    ``hold_rest`` / ``repeat_gait``: clips shorter than ``min_frames`` that end at rest / in
    a steady gait are served whole, then held / their last cycle repeated, up to a crop
    length in [min_frames, max_frames] (module notes); ``settle``: those that end neither,
    but slowly (:data:`SETTLE_SPEED`), are served whole with their end eased to a stop, then
    held (:func:`settle_times`); ``extended`` maps (clip id, person) to the period repeated
    (0: held, :data:`SETTLE`: eased to a stop; its crop length is drawn from the clip's own
    length up, not from ``min_frames``).
    ``caption_mix``: the chance that an item's caption is drawn from a random clip of its
    group instead of its own, the group being the clips that share the metadata keys
    ``caption_mix_within`` (default content label and style) and, of those, only the clips
    whose metadata match every ``caption_mix_from`` "key=value" (e.g. ``style=normal``: the
    unmarked wordings of a label, which then stand for all of its styles). Why: the Bandai
    captions are written per clip and style, so a wording stands for a handful of clips, and
    a small P-Flow learns to copy a few of their crops, the stillest, instead of their
    motion (a wave without its swing; ``results/wave-20261127``, section 10).
    """

    def __init__(
        self,
        corpus: Corpus,
        split: str,
        normalizer: Normalizer | None,
        min_frames: int = 30,
        max_frames: int = 150,
        random_placement: bool = False,
        mirror: bool = True,
        seed: int = 0,
        placement_radius: float = PLACEMENT_RADIUS,
        balance: float = 0.0,
        respell: bool = False,
        hold_rest: bool = False,
        repeat_gait: bool = False,
        settle: bool = False,
        labels: Sequence[str] = (),
        caption_mix: float = 0.0,
        caption_mix_within: Sequence[str] = ("content", "style"),
        caption_mix_from: Sequence[str] = (),
        label_times: Mapping[str, int] | None = None,
    ) -> None:
        super().__init__(seed)
        _check_frames(min_frames, max_frames)
        if not 0 <= balance <= 1:
            raise UMFError(f"balance_labels must be between 0 and 1, got {balance}")
        if not 0 <= caption_mix <= 1:
            raise UMFError(f"caption_mix must be between 0 and 1, got {caption_mix}")
        self.caption_mix = caption_mix
        self.normalizer = normalizer
        self.min_frames, self.max_frames = min_frames, max_frames
        self.random_placement, self.mirror = random_placement, mirror
        self.respell = respell
        self.placement_radius = placement_radius
        self.items: list[tuple[MotionClip, int, RigidTransform]] = []
        for clip in corpus.split_clips(split):
            if clip.num_frames < 2:
                continue
            tf = canonical_transform(torch.from_numpy(np.ascontiguousarray(clip.joints[0])))
            self.items.extend((clip, p, tf) for p in range(clip.num_people))
        if not self.items:
            raise UMFError(f"{corpus.root}: no clips in split {split!r}")
        if labels:
            self.items = _with_labels(self.items, labels, corpus, split)
        # items extended past their end: shorter than every crop, ending at rest or in a gait
        self.extended: dict[tuple[str, int], int] = {}
        if hold_rest or repeat_gait or settle:
            for clip, p, _ in self.items:
                period = extension_period(
                    clip.joints[p], min_frames, hold_rest, repeat_gait, settle
                )
                if period is not None:
                    self.extended[clip.id, p] = period
        if balance or label_times:  # label_times: those labels that many times more again
            contents = [clip.meta.get("content") for clip, _, _ in self.items]
            more = label_times or {}
            repeats = [r * more.get(c, 1) for r, c in
                       zip(label_repeats(contents, balance), contents, strict=True)]  # fmt: skip
            self.items = [
                item for item, r in zip(self.items, repeats, strict=True) for _ in range(r)
            ]
        # the captioned clips of each group (content label, style ...), for caption_mix
        self.mix_within = tuple(caption_mix_within)
        mix_from = metadata_pairs(caption_mix_from)
        self.mix_groups: dict[tuple, list[MotionClip]] = {}
        grouped: set[int] = set()  # each clip once, however often (and wherever) it repeats
        for clip, _, _ in self.items:
            key = self._mix_key(clip)
            donor = all(str(clip.meta.get(k)) == v for k, v in mix_from)
            if key is not None and clip.captions and donor and id(clip) not in grouped:
                grouped.add(id(clip))
                self.mix_groups.setdefault(key, []).append(clip)
        if caption_mix and not self.mix_groups:  # e.g. a corpus without these metadata
            raise UMFError(f"caption_mix: no captioned clip of split {split!r} has the metadata "
                           f"{list(self.mix_within)} and {list(caption_mix_from)}")  # fmt: skip

    def __len__(self) -> int:
        return len(self.items)

    def _mix_key(self, clip: MotionClip) -> tuple | None:
        """The clip's group for caption_mix; None (keeps its own) if a key is missing."""
        key = tuple(clip.meta.get(k) for k in self.mix_within)
        return None if None in key else key

    def _mixed_caption(self, clip: MotionClip, caption: str, rng: np.random.Generator) -> str:
        """With chance ``caption_mix``, a caption of a random clip of the same group (the
        clip itself included; clips without the group's keys keep their own)."""
        group = self.mix_groups.get(self._mix_key(clip), [])  # no key: no group
        if not group or rng.random() >= self.caption_mix:
            return caption
        other = group[int(rng.integers(len(group)))]
        return other.captions[int(rng.integers(len(other.captions)))]

    def __getitem__(self, index: int) -> dict[str, Any]:
        clip, person, tf = self.items[index]
        rng = self._rng(index)
        period = self.extended.get((clip.id, person))
        if period is not None:  # the whole clip, then held or its last cycle repeated
            # an eased clip also at its own length: a flow asked for a getup as long as the
            # real one must not have learnt it only at full-crop lengths
            lo = min(clip.num_frames - 1, self.min_frames) if period == SETTLE else self.min_frames
            start, length = 0, int(rng.integers(lo, self.max_frames + 1))
        else:
            start, length = crop_window(rng, clip.num_frames - 1, self.min_frames, self.max_frames)
        caption = clip.captions[int(rng.integers(len(clip.captions)))] if clip.captions else ""
        if self.caption_mix:  # its own generator, so every other draw stays as without it
            mix_rng = item_rng(self.seed, self.epoch, index, stream=1)
            caption = self._mixed_caption(clip, caption, mix_rng)
        f = canonicalize_features(_clip_crop(clip, tf, [person], start, length, period or 0))[0]
        if self.random_placement:
            yaw = float(rng.uniform(-math.pi, math.pi))
            dx, dz = rng.uniform(-self.placement_radius, self.placement_radius, size=2)
            f = place_features(f, yaw, float(dx), float(dz))
        f, caption, mirrored = _finish(f, self.normalizer, caption, rng, self.mirror, self.respell)
        key = clip.id if clip.num_people == 1 else f"{clip.id}/p{person}"
        # own prompt: half the single-person items repeat their action in it (a stream of
        # its own, so every other draw stays as it was); a person of a take has the take's
        # own caption for them (takes.csv), if any
        own, own_rng = "", item_rng(self.seed, self.epoch, index, stream=2)
        if clip.num_people == 1:
            own = own_caption(clip.captions, own_rng, present=OWN_SINGLE)
        elif clip.meta.get("person_captions"):  # a take's person: what they do in it
            own = own_caption(clip.meta["person_captions"][person], own_rng)
        return {
            "features": f,
            "length": length,
            "caption": caption,
            "person_captions": [mirror_caption(own) if mirrored else own],
            "dataset": SINGLE_PERSON if clip.num_people == 1 else MULTI_PERSON,
            "id": key,
            "start": start,
            "mirrored": mirrored,
        }

    @staticmethod
    def collate(items: list[dict[str, Any]]) -> dict[str, Any]:
        return collate_single(items)


# --------------------------------------------------------------------- scenes
def crop_recipe(recipe: dict[str, Any], actors: dict, start: int, length: int) -> dict[str, Any]:
    """The recipe of frames [start, start + length] of a composed scene (joint frames).

    Equivalent to building the whole scene and cropping it, at the cost of the crop only.
    """
    people = []
    for p in recipe["people"]:
        delay, first = p["delay"], p["start"]
        if start < delay:
            delay, first = delay - start, first
        else:
            n = actors[p["clip"]].joints.shape[0]
            delay, first = 0, min(first + start - delay, n - 1)
        people.append({**p, "delay": delay, "start": first})
    return {**recipe, "num_frames": length, "people": people}


# relations whose person 1 walks up to someone: carried on, they would walk past them
# (the scene ends where they meet; umf.data.extension.scene_gait_periods)
LEADER_STOPS = ("walk_toward",)


class SceneDataset(_EpochDataset):
    """One multi-person scene per item, cropped in time for everybody, in person 1's frame.

    Serves the split's composed scenes and, with ``real_clips``, its real multi-person
    clips (InterHuman, mocap takes; each ``real_repeats`` times, with a crop of its own each
    time). ``relation_repeats``: composed scenes of those relations that many times each.
    Scenes with more than ``max_people`` people are left out rather than truncated: their
    captions count everybody. ``respell``: as in :class:`SingleMotionDataset`.
    ``repeat_gait``: a composed scene shorter than ``min_frames`` whose people travel
    together and all end in a steady gait, and whose relation still holds when they go on,
    is served from its start at a crop length from ``min_frames`` to ``max_frames``, each
    person's last cycle repeated
    (:func:`umf.data.extension.scene_gait_periods`); ``extended`` maps its id to the periods.
    ``leader_gait`` (the P-Flow, which learns person 1 alone): a short composed scene whose
    person 1 ends in a steady, straight gait (:func:`umf.data.extension.gait_period`) is
    served the same way, person 1's last cycle repeated and everyone else held in their last
    pose, except where person 1 walks up to the other (:data:`LEADER_STOPS`).
    """

    def __init__(
        self,
        corpus: Corpus,
        split: str,
        normalizer: Normalizer | None,
        min_frames: int = 30,
        max_frames: int = 150,
        mirror: bool = True,
        seed: int = 0,
        max_people: int | None = None,
        real_clips: bool = True,
        respell: bool = False,
        real_repeats: int = 1,
        relation_repeats: Mapping[str, int] | None = None,
        repeat_gait: bool = False,
        leader_gait: bool = False,
    ) -> None:
        super().__init__(seed)
        if real_repeats < 1:
            raise UMFError(f"real_repeats must be at least 1, got {real_repeats}")
        times = dict(relation_repeats or {})
        self.respell = respell
        _check_frames(min_frames, max_frames)
        self.corpus, self.normalizer = corpus, normalizer
        self.min_frames, self.max_frames, self.mirror = min_frames, max_frames, mirror
        fits = lambda n: n >= 2 and (max_people is None or n <= max_people)  # noqa: E731
        self.items: list[tuple[str, Any, RigidTransform | None]] = [
            ("scene", r, None)
            for r in corpus.scenes.get(split, [])
            if fits(r["num_people"]) and r["num_frames"] >= 2
            for _ in range(times.get(r.get("relation", ""), 1))
        ]
        if real_clips:
            for clip in corpus.split_clips(split):
                if fits(clip.num_people) and clip.num_frames >= 2:
                    tf = canonical_transform(torch.from_numpy(np.ascontiguousarray(clip.joints[0])))
                    self.items.extend([("clip", clip, tf)] * real_repeats)
        if not self.items:
            raise UMFError(f"{corpus.root}: no multi-person scenes in split {split!r}")
        corpus.actors()  # built once here, so worker processes inherit it
        self.clip_captions = {c.id: c.captions for c in corpus.clips}
        self.extended: dict[str, list[int]] = {}
        # each distinct short scene once (relation_repeats serve some again)
        short = {r["id"]: r for kind, r, _ in self.items
                 if kind == "scene" and r["num_frames"] - 1 < min_frames}  # fmt: skip
        for sid, r in short.items() if repeat_gait else ():
            periods = scene_gait_periods(corpus.scene_joints(r), r, max_frames + 1)
            if periods is not None:
                self.extended[sid] = periods
        for sid, r in short.items() if leader_gait else ():
            if sid not in self.extended and r.get("relation") not in LEADER_STOPS:
                period = gait_period(corpus.scene_joints(r)[0])
                if period:
                    self.extended[sid] = [period] + [0] * (r["num_people"] - 1)

    def _own_captions(self, kind: str, item: Any, index: int) -> list[str]:
        """Each person's own caption: a wording of the clip a composed person plays
        (mirrored with the person); for a real take, its ``person_captions`` (takes.csv's
        caption column), "" where it has none."""
        rng = item_rng(self.seed, self.epoch, index, stream=2)
        if kind == "clip":
            own = item.meta.get("person_captions") or [[]] * item.num_people
            return [own_caption(c, rng) for c in own][: item.num_people]
        out = []
        for p in item["people"]:
            own = own_caption(self.clip_captions.get(p["clip"], []), rng)
            out.append(mirror_caption(own) if p.get("mirrored") else own)
        return out

    def __len__(self) -> int:
        return len(self.items)

    def _crop(self, kind: str, item: Any, tf, start: int, length: int) -> Tensor:
        if kind == "clip":
            return _clip_crop(item, tf, range(item.num_people), start, length)
        periods = self.extended.get(item["id"])
        if periods is not None:  # the whole scene, each person's last cycle repeated
            actors = self.corpus.actors()
            joints, rot = extend_scene(build_scene(item, actors), scene_rotations(item, actors),
                                       periods, start, start + length + 1)  # fmt: skip
            return torch.from_numpy(scene_features_of(joints, rot))
        recipe = crop_recipe(item, self.corpus.actors(), start, length + 1)
        return torch.from_numpy(self.corpus.scene_features(recipe))

    def whole(self, index: int) -> Tensor:
        """The whole scene or take item ``index`` crops from, features (N, T, 262)
        de-normalised, neither mirrored nor carried on: what a crop's people did before and
        after it (an answer's delay, :mod:`umf.train.reactions`)."""
        kind, item, tf = self.items[index]
        total = (item.num_frames if kind == "clip" else item["num_frames"]) - 1
        return self._crop(kind, item, tf, 0, total)

    def __getitem__(self, index: int) -> dict[str, Any]:
        kind, item, tf = self.items[index]
        rng = self._rng(index)
        total = (item.num_frames if kind == "clip" else item["num_frames"]) - 1
        if kind == "scene" and item["id"] in self.extended:
            start, length = 0, int(rng.integers(self.min_frames, self.max_frames + 1))
        else:
            start, length = crop_window(rng, total, self.min_frames, self.max_frames)
        captions = item.captions if kind == "clip" else item["captions"]
        caption = captions[int(rng.integers(len(captions)))] if captions else ""
        f = canonicalize_features(self._crop(kind, item, tf, start, length))
        f, caption, mirrored = _finish(f, self.normalizer, caption, rng, self.mirror, self.respell)
        own = self._own_captions(kind, item, index)
        return {
            "features": f,
            "length": length,
            "num_people": int(f.shape[0]),
            "caption": caption,
            "person_captions": [mirror_caption(c) if mirrored else c for c in own],
            "dataset": MULTI_PERSON,
            "id": item.id if kind == "clip" else item["id"],
            "start": start,
            "mirrored": mirrored,
        }

    @staticmethod
    def collate(items: list[dict[str, Any]]) -> dict[str, Any]:
        return collate_scenes(items)
