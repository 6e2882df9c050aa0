"""Build a model's bank of real reactions from the corpus it was trained on
(:mod:`umf.reaction_bank`; ``umf train reactions``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from umf.coverage import embed
from umf.data.corpus import Corpus
from umf.data.relations import measured_relation
from umf.errors import UMFError
from umf.reaction_bank import ReactionBank
from umf.representation import canonicalize_features, floor_start
from umf.train.datasets import SceneDataset, _clip_crop
from umf.warm_start import floor_velocity, onsets

STEP = 15  # feature frames between stored lengths: the evaluation's --length-step
TAKE_STEP = 30  # feature frames between the starts of a touching take's stored crops


class NoReactions(UMFError):
    """A corpus without multi-person train scenes: there is no reaction to store."""


def bank_lengths(max_frames: int, step: int = STEP, shortest: int = 30) -> list[int]:
    """The lengths a bank stores: every ``step`` frames from ``shortest`` to ``max_frames``."""
    return list(range(shortest, max_frames + 1, step))


@torch.no_grad()
def build_reaction_bank(
    corpus_dir: str | Path,
    pipe,
    lengths: Sequence[int] | None = None,
    per_length: int = 1024,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> ReactionBank:
    """People 2..N of the train split's scenes and real takes, cropped to each length in
    person 1's frame (mirrored at random, as in training; short striding scenes carried on
    where the S-Flow's ``train_sflow.repeat_scene_gait`` says), as the VAE's posterior means, with
    their scene's caption embedded by the model's text encoder, their pelvis's mean floor
    velocity, where they start and, for people who answer person 1, how many frames after
    person 1's their action starts in the whole scene (a crop may cut either onset;
    :func:`answer_waits`); at most ``per_length`` per length, drawn with ``seed``; and both
    people of the real takes whose people touch, every :data:`TAKE_STEP` frames
    (:func:`touching_crops`).
    A length no scene is long enough for is left out; a corpus without multi-person train
    scenes raises :class:`NoReactions`."""
    corpus = Corpus.load(corpus_dir)
    if not corpus.scenes.get("train") and not any(
        c.num_people > 1 for c in corpus.split_clips("train")
    ):
        raise NoReactions(f"{corpus_dir}: no multi-person train scene to take reactions from")
    lengths = list(lengths or bank_lengths(pipe.config.vae.max_frames))
    rng = np.random.default_rng(seed)
    latents: dict[int, torch.Tensor] = {}
    texts: dict[int, torch.Tensor] = {}
    velocities: dict[int, torch.Tensor] = {}
    lags: dict[int, torch.Tensor] = {}
    starts: dict[int, torch.Tensor] = {}
    takes: dict[int, torch.Tensor] = {}
    take_texts: dict[int, torch.Tensor] = {}
    cuts: dict[int, list[tuple[str, int]]] = {}  # per length, where each take crop was cut
    whole_lags: dict[str, list[int]] = {}  # per scene or take, its people's delays
    for frames in tqdm(lengths, desc="reactions", unit="length", disable=not progress):
        ds = SceneDataset(corpus, "train", pipe.normalizer, min_frames=frames,
                          max_frames=frames, mirror=True, seed=seed,
                          repeat_gait=pipe.config.train_sflow.repeat_scene_gait)  # fmt: skip
        people, captions, lag = [], [], []
        for i in range(len(ds)):
            item = ds[i]
            f = item["features"]
            if f.shape[1] == frames:
                people.extend(f[1:])
                captions.extend([item["caption"]] * (f.shape[0] - 1))
                if item["id"] not in whole_lags:  # a scene served again: the same delays
                    whole_lags[item["id"]] = answer_waits(ds, i)
                lag.extend(whole_lags[item["id"]])
        if not people:
            log(f"reactions: no train scene has {frames} frames; that length is left out")
            continue
        keep = np.sort(rng.permutation(len(people))[:per_length])
        x = torch.stack([people[i] for i in keep]).to(pipe.device)
        mask = torch.ones(x.shape[:2], dtype=torch.bool, device=x.device)
        chosen = [captions[i] for i in keep]
        distinct = sorted(set(chosen))  # a scene's caption is shared by its people and crops
        row = {c: i for i, c in enumerate(distinct)}
        texts[frames] = embed(pipe.text_encoder, distinct)[[row[c] for c in chosen]]
        lags[frames] = torch.tensor([lag[i] for i in keep], dtype=torch.float32)
        real = pipe.normalizer.denormalize(x.cpu())
        velocities[frames] = floor_velocity(real, pipe.config.fps)
        starts[frames] = floor_start(real)
        latents[frames] = torch.cat([pipe.vae.encode(x[j : j + 256], mask[j : j + 256])[0].cpu()
                                     for j in range(0, len(x), 256)])  # fmt: skip
        crops, take_captions, cuts[frames] = touching_crops(ds, frames)
        if crops:
            x = pipe.normalizer.normalize(torch.stack(crops)).to(pipe.device)  # (N, 2, T, F)
            whole = torch.ones(x.shape[0] * 2, frames, dtype=torch.bool, device=x.device)
            pairs = zip(x.flatten(0, 1).split(256), whole.split(256), strict=True)
            z = torch.cat([pipe.vae.encode(c, m)[0].cpu() for c, m in pairs])
            takes[frames] = z.reshape(len(crops), 2, *z.shape[1:])
            most = max(len(c) for c in take_captions)
            distinct = sorted({c for cs in take_captions for c in cs})
            table = embed(pipe.text_encoder, distinct)
            e = torch.full((len(crops), most, table.shape[1]), torch.nan)
            for i, cs in enumerate(take_captions):
                e[i, : len(cs)] = table[[distinct.index(c) for c in cs]]
            take_texts[frames] = e
    if not latents:
        raise NoReactions(f"{corpus_dir}: no multi-person train scene to take reactions from")
    names = sorted({c for cut in cuts.values() for c, _ in cut})
    sources = {k: torch.tensor([[names.index(c), f] for c, f in cuts[k]]) for k in takes}
    return ReactionBank(latents, texts, velocities, lags, starts, takes, take_texts, sources,
                        names)  # fmt: skip


def touching_crops(
    ds: SceneDataset, frames: int
) -> tuple[list[torch.Tensor], list[list[str]], list[tuple[str, int]]]:
    """People 1 and 2 of each real take the dataset serves who touch
    (:func:`umf.data.relations.measured_relation` on those two: the crops hold them), cropped
    to ``frames`` every :data:`TAKE_STEP` frames in person 1's frame, neither mirrored nor
    carried on: features (2, frames, 262) de-normalised, each crop's take's captions, and
    where it was cut (the take's clip id, its first frame)."""
    crops, captions, cut, seen = [], [], [], set()
    for kind, clip, tf in ds.items:
        if kind != "clip" or clip.id in seen or clip.num_frames - 1 < frames:
            continue
        seen.add(clip.id)
        if not clip.captions or not measured_relation(clip.joints[:2])["touching"]:
            continue
        for start in range(0, clip.num_frames - 1 - frames + 1, TAKE_STEP):
            whole = _clip_crop(clip, tf, range(2), start, frames)
            crops.append(canonicalize_features(torch.as_tensor(whole)).float())
            captions.append(sorted(set(clip.captions)))
            cut.append((clip.id, start))
    return crops, captions, cut


def answer_waits(ds: SceneDataset, index: int) -> list[int]:
    """For people 2..N of the scene item ``index`` crops from: the frames from person 1's
    action onset to theirs in the whole scene, for those its relation says answer person 1
    (a ``starts_after`` check from person 1 to them: a bow back, a response, an audience);
    0 for everybody else. People who act together (walking side by side, a real salsa take)
    start when they start, and their onsets differ for no reason a prompt names: read as
    waits, the salsa follower turned into an answer and stopped facing the leader."""
    kind, item, _ = ds.items[index]
    people = item.num_people if kind == "clip" else len(item["people"])
    answering = set()
    if kind == "scene":
        answering = {c.get("b", 1) for c in item["constraints"]
                     if c["type"] == "starts_after" and c.get("a", 0) == 0}  # fmt: skip
    if not answering:
        return [0] * (people - 1)
    start = onsets(ds.whole(index))
    return [start[k] - start[0] if k in answering else 0 for k in range(1, people)]


def write_reactions(
    model: str | Path,
    corpus_dir: str | Path,
    per_length: int = 1024,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> ReactionBank:
    """Give a model directory the bank of the corpus it was trained on."""
    from umf.pipeline import UMFPipeline

    bank = build_reaction_bank(corpus_dir, UMFPipeline.from_pretrained(model),
                               per_length=per_length, progress=progress, log=log)  # fmt: skip
    bank.save(model)
    return bank
