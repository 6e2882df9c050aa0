"""What a model knows: its training vocabulary, and how well a prompt is covered by it.

A model directory carries ``vocabulary.json`` (the distinct captions it was trained on, its
actions, styles and multi-person relations) and ``vocabulary.safetensors`` (each caption's
sentence embedding in the model's own frozen text encoder: the masked mean of its token
states, unit length). A prompt's coverage is its cosine similarity to the nearest trained
caption: ``{"score": float, "known": score >= threshold, "nearest": [captions]}``. (Dropping
the words that count people from both sides was tried and separates worse: AUC 0.959 against
0.968 on the calibration lists.)

Groups of 3 or more are not trained scenes: the pipeline composes them at sampling, each
person k >= 3 a reaction to everyone before them. What the model can be asked for is the
group relations its corpus composes (rows, single files, circles, audiences, gatherings), so
the vocabulary also holds the captions of groups composed from the training clips, as the
corpus composes its test groups (``groups`` names those relations).

The threshold is calibrated on paraphrases of trained actions against actions no bundled
corpus has (``research/calibrate_coverage.py``; precision and recall in docs/model.md).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from umf.errors import UMFError
from umf.io import save_tensors_atomic, write_json_atomic

VOCABULARY_JSON = "vocabulary.json"
VOCABULARY_TENSORS = "vocabulary.safetensors"
THRESHOLD = 0.714  # calibrated on the bundled corpus: research/calibrate_coverage.py, docs/model.md
NEAREST = 3
GROUP_SCENES = 300  # composed groups whose captions join the vocabulary (they saturate by 200)
GROUP_SEED = 23


@dataclass
class Vocabulary:
    """A model's training vocabulary (module notes); ``embeddings`` (N, D) unit rows."""

    phrases: list[str]
    embeddings: torch.Tensor
    encoder: str
    threshold: float = THRESHOLD
    actions: list[str] = field(default_factory=list)
    styles: list[str] = field(default_factory=list)
    relations: list[str] = field(default_factory=list)
    groups: list[str] = field(default_factory=list)  # relations of 3+ people (module notes)
    # captions of real takes whose people touch -> how close they come (umf.separation)
    contact: dict[str, dict[str, float]] = field(default_factory=dict)

    def save(self, model_dir: str | Path) -> None:
        model_dir = Path(model_dir)
        save_tensors_atomic({"embeddings": self.embeddings.to(torch.float16).contiguous()},
                            model_dir / VOCABULARY_TENSORS)  # fmt: skip
        (model_dir / VOCABULARY_TENSORS).chmod(0o644)
        write_json_atomic(model_dir / VOCABULARY_JSON, {
            "encoder": self.encoder, "threshold": self.threshold, "actions": self.actions,
            "styles": self.styles, "relations": self.relations, "groups": self.groups,
            "phrases": self.phrases,
            "contact": self.contact,
        })  # fmt: skip

    @classmethod
    def load(cls, model_dir: str | Path) -> Vocabulary | None:
        """The model's vocabulary, or None for a model trained before vocabularies."""
        from safetensors.torch import load_file

        model_dir = Path(model_dir)
        if not (model_dir / VOCABULARY_JSON).exists():
            return None
        try:
            doc = json.loads((model_dir / VOCABULARY_JSON).read_text())
            emb = load_file(str(model_dir / VOCABULARY_TENSORS))["embeddings"].float()
            phrases = [str(p) for p in doc["phrases"]]
            threshold = float(doc["threshold"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UMFError(f"{model_dir}: corrupt vocabulary ({type(exc).__name__})") from None
        if emb.ndim != 2 or emb.shape[0] != len(phrases) or not torch.isfinite(emb).all():
            raise UMFError(f"{model_dir}: vocabulary embeddings do not match its phrases")
        contact = doc.get("contact", {})
        if not isinstance(contact, dict):
            raise UMFError(f"{model_dir}: corrupt vocabulary (contact)")
        names = {}
        for key in ("actions", "styles", "relations", "groups"):
            value = doc.get(key, [])
            if not isinstance(value, list):
                raise UMFError(f"{model_dir}: corrupt vocabulary ({key})")
            names[key] = [str(v) for v in value]
        return cls(phrases, emb, str(doc.get("encoder", "")), threshold, **names,
                   contact=contact)  # fmt: skip

    def score(self, prompts: Sequence[str], encoder) -> list[dict[str, Any]]:
        """Coverage of each prompt (module notes), in the encoder the vocabulary was built with."""
        if not prompts:
            return []
        q = embed(encoder, list(prompts))
        sims = q @ self.embeddings.T.to(q.dtype)
        k = min(NEAREST, sims.shape[1])
        top, idx = sims.topk(k, dim=1)
        out = []
        for row, ids in zip(top.tolist(), idx.tolist(), strict=True):
            s = float(row[0])
            cov = {"score": round(s, 4), "known": bool(s >= self.threshold),
                   "nearest": [self.phrases[i] for i in ids]}  # fmt: skip
            touch = self.contact.get(self.phrases[ids[0]])
            if cov["known"] and touch is not None:
                cov["contact"] = dict(touch)  # a prompt worded like a touching take's caption
            out.append(cov)
        return out


@torch.no_grad()
def embed(encoder, texts: Sequence[str], batch: int = 256) -> torch.Tensor:
    """Unit sentence embeddings (N, D) of ``texts`` from a frozen encoder's pooled states."""
    rows = []
    for i in range(0, len(texts), batch):
        pooled = encoder.encode(list(texts[i : i + batch])).pooled.float().cpu()
        rows.append(torch.nn.functional.normalize(pooled, dim=-1))
    return torch.cat(rows) if rows else torch.zeros(0, encoder.dim)


def build_vocabulary(
    corpus, encoder, encoder_name: str, threshold: float = THRESHOLD
) -> Vocabulary:
    """The vocabulary of a corpus: its distinct training captions (clips, scenes and groups
    composed from its training clips), its content labels, styles and scene relations."""
    clips = corpus.split_clips("train")
    texts: set[str] = set()
    actions, styles, relations = set(), set(), set()
    for c in clips:
        texts.update(c.captions)
        if c.meta.get("content"):
            actions.add(str(c.meta["content"]))
        if c.meta.get("style"):
            styles.add(str(c.meta["style"]))
        if c.num_people > 1:
            relations.add(str(c.meta.get("content") or "real take"))
    for r in corpus.scenes.get("train", []):
        texts.update(r["captions"])
        relations.add(str(r["relation"]))
    group_records = train_groups(corpus)
    for r in group_records:
        texts.update(r["captions"])
    groups = sorted({str(r["relation"]) for r in group_records})
    contact = take_contacts(clips)
    phrases = sorted(t for t in texts if t.strip())
    return Vocabulary(phrases, embed(encoder, phrases), encoder_name, threshold,
                      sorted(actions), sorted(styles), sorted(relations), groups,
                      contact)  # fmt: skip


def train_groups(corpus, count: int = GROUP_SCENES) -> list[dict[str, Any]]:
    """Groups of the corpus's sizes composed from its training clips, as its test groups are
    composed from its test clips (:func:`umf.data.composer.compose_corpus`)."""
    from umf.data.composer import compose_corpus
    from umf.data.scene_relations import RELATIONS

    sizes = tuple(corpus.manifest.get("config", {}).get("group_sizes", (3, 4, 5, 6)))
    names = [n for n, r in RELATIONS.items() if any(s > 2 for s in r.sizes)]
    actors = corpus.actors()
    train = [actors[c.id] for c in corpus.split_clips("train") if c.id in actors]
    return compose_corpus(train, count, sizes, seed=GROUP_SEED, relations=names)


def take_contacts(clips) -> dict[str, dict[str, float]]:
    """For each caption of a real multi-person take whose people touch
    (:func:`umf.data.relations.measured_relation`), how close its people come: the smallest
    over those takes of the 5th-percentile closest-joints and pelvis distances. What the
    data holds close, the clean-up lets stay close."""
    from umf.data.relations import measured_relation

    out: dict[str, dict[str, float]] = {}
    for c in clips:
        if c.num_people < 2:
            continue
        measured = measured_relation(c.joints)
        if not measured["touching"]:
            continue
        pairs = list(measured["pairs"].values())
        near = {"closest_m": min(p["closest_p05_m"] for p in pairs),
                "pelvis_m": min(p["pelvis_p05_m"] for p in pairs)}  # fmt: skip
        for caption in c.captions:
            have = out.get(caption)
            out[caption] = near if have is None else {k: min(have[k], near[k]) for k in near}
    return out


def warning_line(prompt: str, cov: dict[str, Any]) -> str:
    """The one line ``umf generate`` / ``react`` print for a prompt the model does not know."""
    near = "; ".join(f'"{p}"' for p in cov["nearest"])
    return (
        f"umf: warning: {prompt!r} is outside what this model was trained on (coverage "
        f"{cov['score']:.2f}); nearest known: {near}; `umf info` lists what it knows"
    )
