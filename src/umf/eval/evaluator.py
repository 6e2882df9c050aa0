"""The contrastive text-motion evaluator (InterGen's "InterCLIP" architecture, SPEC 8).

Motion side: each person's 262 features without the 4 foot contacts (258), people
concatenated per frame (2 x 258 for the ``interaction`` kind, 258 for ``single``) ->
Linear -> a learned query token prepended -> sinusoidal positions -> post-norm
transformer -> LayerNorm -> the query token's output -> Linear -> embedding.
Text side: token vectors + positional embeddings -> post-norm transformer -> LayerNorm ->
the end-of-text token's output -> Linear -> embedding. Both embeddings are L2-normalised
and multiplied by a learned ``latent_scale``; the loss is CLIP's symmetric cross-entropy
on their dot products (``latent_scale^2`` times the cosine), as in InterGen.

Token vectors come from one of three sources (``EvaluatorConfig.text_encoder``):

- ``"minilm"`` (default) or ``"clip"``: the frozen token states of the project's text
  encoder (:mod:`umf.text`, cached on disk), through a trained ``Linear``; padding is
  masked and the last real token ([SEP] / end-of-text) is read out.
- ``"clip-tokens"``: InterGen's layout: CLIP ViT-L/14's token embedding table (frozen) and
  its 77 positional embeddings over the raw token ids, every one of the 77 positions
  attended (no padding mask), the end-of-text token found as the largest id. This is
  what :func:`load_interclip` builds from InterGen's released ``interclip.ckpt``.

Inputs are **raw** (de-normalised) features in person 1's canonical frame, like the
pipeline's ``Scene.features``; the module applies its own stored per-dimension
normalisation (the identity for InterGen's weights: InterGen scores de-normalised motions).
``frames_per_token > 1`` (the ``small`` family: 4) concatenates consecutive frames into one
motion token, our deviation to make a CPU run affordable; 1 is InterCLIP exactly.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from umf.config import EvaluatorConfig
from umf.errors import UMFError
from umf.models.vae import sinusoidal_embedding
from umf.representation import CONTACT, FEATURE_DIM, Normalizer
from umf.text import TextFeatures, last_real

KINDS = {"interaction": 2, "single": 1}
MOTION_DIM = CONTACT.start  # 258: a person's features without foot contacts
PE_LENGTH = 2000  # rows of the sinusoidal table (InterGen's length; covers 66 s at 30 fps)
CLIP_CONTEXT = 77

TextInputs = TextFeatures | Tensor  # frozen token states, or CLIP token ids (B, 77)


class TextSource(Protocol):
    """Turns prompts into what the text tower reads (token states or token ids)."""

    def encode(self, texts: list[str]) -> TextInputs: ...


# --------------------------------------------------------------------- pure helpers
def motion_inputs(features: Tensor, num_people: int) -> Tensor:
    """(B, P, T, 262) (or (B, T, 262) for one person) -> (B, T, P * 258), contacts dropped.

    People are concatenated per frame in order (person 1 first), as InterGen stacks them.
    """
    if features.dim() == 3 and num_people == 1:
        features = features[:, None]
    if features.dim() != 4 or features.shape[-1] != FEATURE_DIM:
        raise ValueError(f"expected features (B, P, T, {FEATURE_DIM}), got {tuple(features.shape)}")
    if features.shape[1] != num_people:
        raise ValueError(f"this evaluator scores {num_people} people, got {features.shape[1]}")
    x = features[..., :MOTION_DIM].transpose(1, 2)  # (B, T, P, 258)
    return x.reshape(x.shape[0], x.shape[1], num_people * MOTION_DIM)


def patch_frames(x: Tensor, mask: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """(B, T, C), (B, T) -> (B, ceil(T/k), k*C), (B, ceil(T/k)): k frames per token.

    Padding frames are zero and a token is valid when its first frame is (right padding).
    """
    if k == 1:
        return x, mask
    b, t, c = x.shape
    pad = (-t) % k
    x = F.pad(x * mask[..., None].to(x.dtype), (0, 0, 0, pad))
    return x.reshape(b, (t + pad) // k, k * c), F.pad(mask, (0, pad))[:, ::k]


def scaled_unit(x: Tensor, scale: Tensor) -> Tensor:
    """x / ||x|| * scale: the evaluator's embedding convention (InterGen)."""
    return F.normalize(x, dim=-1) * scale


def clip_loss(motion_emb: Tensor, text_emb: Tensor, positives: Tensor | None = None) -> Tensor:
    """Symmetric InfoNCE on logits ``motion_emb @ text_emb.T``.

    ``positives`` (B, B) bool marks pairs that must not count as negatives (same caption,
    same scene); they are removed from both softmaxes, the diagonal stays the target.
    """
    logits = motion_emb @ text_emb.T
    b = logits.shape[0]
    eye = torch.eye(b, dtype=torch.bool, device=logits.device)
    if positives is not None:
        logits = logits.masked_fill(positives.to(logits.device) & ~eye, float("-inf"))
    target = torch.arange(b, device=logits.device)
    return 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))


def same_pairs(captions: Sequence[str], ids: Sequence[str] | None = None) -> Tensor:
    """(B, B) bool: True where two items share a caption (or an id): not negatives."""
    keys = list(captions)
    codes = {c: i for i, c in enumerate(dict.fromkeys(keys))}
    c = torch.tensor([codes[k] for k in keys])
    out = c[:, None] == c[None, :]
    if ids is not None:
        id_codes = {k: i for i, k in enumerate(dict.fromkeys(ids))}
        d = torch.tensor([id_codes[k] for k in ids])
        out |= d[:, None] == d[None, :]
    return out


def _encoder(width: int, heads: int, ff: int, layers: int, dropout: float) -> nn.TransformerEncoder:
    """Post-norm GELU transformer, batch first: InterCLIP's layer type."""
    layer = nn.TransformerEncoderLayer(
        width, heads, ff, dropout, activation="gelu", batch_first=True, norm_first=False
    )
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


# --------------------------------------------------------------------- towers
class MotionTower(nn.Module):
    """Frames of P people -> one embedding (unnormalised) via a prepended query token."""

    def __init__(self, cfg: EvaluatorConfig, num_people: int):
        super().__init__()
        self.num_people = num_people
        self.frames_per_token = cfg.frames_per_token
        in_dim = num_people * MOTION_DIM
        self.register_buffer("in_mean", torch.zeros(in_dim))
        self.register_buffer("in_std", torch.ones(in_dim))
        self.query = nn.Parameter(torch.randn(1, cfg.d_model))
        self.embed = nn.Linear(in_dim * cfg.frames_per_token, cfg.d_model)
        self.register_buffer("pe", sinusoidal_embedding(PE_LENGTH, cfg.d_model), persistent=False)
        self.pe_dropout = nn.Dropout(cfg.dropout)
        self.encoder = _encoder(cfg.d_model, cfg.num_heads, cfg.ff_dim, cfg.num_layers, cfg.dropout)
        self.out_ln = nn.LayerNorm(cfg.d_model)
        self.out = nn.Linear(cfg.d_model, cfg.embed_dim)

    def forward(self, features: Tensor, mask: Tensor | None = None) -> Tensor:
        x = motion_inputs(features, self.num_people)
        b, t = x.shape[:2]
        x = (x - self.in_mean) / self.in_std
        valid = torch.ones(b, t, dtype=torch.bool, device=x.device) if mask is None else mask
        x, valid = patch_frames(x, valid.bool(), self.frames_per_token)
        t = x.shape[1]
        if t + 1 > PE_LENGTH:
            raise ValueError(f"{t} motion tokens > the evaluator's limit of {PE_LENGTH - 1}")
        valid = torch.cat([torch.ones_like(valid[:, :1]), valid], dim=1)
        h = torch.cat([self.query.expand(b, 1, -1), self.embed(x)], dim=1)
        h = self.pe_dropout(h + self.pe[: t + 1])
        h = self.encoder(h, src_key_padding_mask=~valid)
        return self.out(self.out_ln(h)[:, 0])


class TextTower(nn.Module):
    """Token vectors -> transformer -> the end-of-text output -> embedding (unnormalised).

    ``vocab_size`` set: InterGen's CLIP-token layout (frozen token table, 77 positions,
    no padding mask, EOT = largest id). Otherwise: frozen-encoder states (``in_dim``) through
    a trained ``Linear``, padding masked, the last real token read out.
    """

    def __init__(self, cfg: EvaluatorConfig, in_dim: int | None, vocab_size: int | None):
        super().__init__()
        w = cfg.text_width
        self.clip_tokens = vocab_size is not None
        if self.clip_tokens:
            self.token_embedding = nn.Embedding(int(vocab_size), w).requires_grad_(False)
            self.pos = nn.Parameter(torch.empty(CLIP_CONTEXT, w).normal_(std=0.01))
        else:
            if in_dim is None:
                raise ValueError("TextTower needs in_dim (frozen token states) or vocab_size")
            self.in_proj = nn.Linear(in_dim, w)
            self.pos = nn.Parameter(torch.empty(cfg.text_max_length, w).normal_(std=0.02))
        self.encoder = _encoder(w, cfg.text_heads, cfg.text_ff_dim, cfg.text_layers, cfg.dropout)
        self.out_ln = nn.LayerNorm(w)
        self.out = nn.Linear(w, cfg.embed_dim)

    def forward(self, inputs: TextInputs) -> Tensor:
        if self.clip_tokens:
            if not isinstance(inputs, Tensor) or inputs.shape[-1] != self.pos.shape[0]:
                raise ValueError(f"expected CLIP token ids (B, {self.pos.shape[0]})")
            h = self.encoder(self.token_embedding(inputs) + self.pos)
            return self.out(self.out_ln(h)[torch.arange(h.shape[0]), inputs.argmax(dim=-1)])
        if not isinstance(inputs, TextFeatures):
            raise ValueError("expected frozen token states (TextFeatures)")
        length = inputs.tokens.shape[1]
        if length > self.pos.shape[0]:
            raise ValueError(f"{length} text tokens > text_max_length {self.pos.shape[0]}")
        h = self.in_proj(inputs.tokens) + self.pos[:length]
        h = self.encoder(h, src_key_padding_mask=~inputs.mask)
        return self.out(last_real(self.out_ln(h), inputs.mask))


# --------------------------------------------------------------------- the evaluator
class MotionTextEvaluator(nn.Module):
    """Text and motion embeddings in one space (norm ``latent_scale``), for the metrics.

    ``kind``: ``"interaction"`` (two people) or ``"single"``. The text source (frozen
    encoder cache or CLIP tokenizer) is attached, not registered: it is not part of the
    weights.
    """

    def __init__(
        self,
        cfg: EvaluatorConfig,
        kind: str = "interaction",
        text_dim: int | None = 384,
        vocab_size: int | None = None,
    ):
        super().__init__()
        if kind not in KINDS:
            raise UMFError(f"unknown evaluator kind {kind!r} (choose {', '.join(KINDS)})")
        self.cfg, self.kind = cfg, kind
        self.num_people = KINDS[kind]
        self.motion = MotionTower(cfg, self.num_people)
        self.text = TextTower(cfg, text_dim, vocab_size)
        self.latent_scale = nn.Parameter(torch.tensor([float(cfg.latent_scale_init)]))
        self.text_source: TextSource | None = None

    def set_normalizer(self, normalizer: Normalizer) -> None:
        """Store the corpus feature mean/std (contacts dropped, tiled per person)."""
        with torch.no_grad():
            self.motion.in_mean.copy_(normalizer.mean[:MOTION_DIM].repeat(self.num_people))
            self.motion.in_std.copy_(normalizer.std[:MOTION_DIM].repeat(self.num_people))

    def attach_text(self, source: TextSource) -> MotionTextEvaluator:
        self.text_source = source
        return self

    @property
    def device(self) -> torch.device:
        return self.latent_scale.device

    def text_inputs(self, texts: Sequence[str]) -> TextInputs:
        if self.text_source is None:
            raise UMFError("the evaluator has no text source attached (attach_text)")
        out = self.text_source.encode(list(texts))
        return out.to(self.device)

    def embed_text(self, inputs: TextInputs) -> Tensor:
        """(B, E) embeddings of prepared text inputs."""
        return scaled_unit(self.text(inputs), self.latent_scale)

    def encode_text(self, texts: Sequence[str]) -> Tensor:
        """(B, E) embeddings of prompts (needs an attached text source)."""
        return self.embed_text(self.text_inputs(texts))

    def encode_motion(self, features: Tensor, mask: Tensor | None = None) -> Tensor:
        """(B, E) embeddings of raw features (B, P, T, 262); ``mask`` (B, T) True on frames."""
        return scaled_unit(self.motion(features, mask), self.latent_scale)

    def forward(
        self, features: Tensor, mask: Tensor | None, text: TextInputs
    ) -> tuple[Tensor, Tensor]:
        return self.encode_motion(features, mask), self.embed_text(text)


# --------------------------------------------------------------------- text sources
class ClipTokenIds:
    """CLIP token ids as openai's ``clip.tokenize(truncate=True)`` lays them out.

    [start] + BPE + [end], cut to 77 with the end token kept last, zero-padded to 77.
    Hugging Face's ``CLIPTokenizer`` (same BPE vocabulary and lower-casing) reads the
    tokenizer files of a local CLIP directory; a directory without usable files is an
    error (offline, ``from_pretrained`` may otherwise return a 2-token tokenizer).
    """

    def __init__(self, clip_dir: str | os.PathLike | None, context: int = CLIP_CONTEXT):
        from transformers import CLIPTokenizer

        if clip_dir is None or not Path(clip_dir).is_dir():
            raise UMFError(
                f"InterGen's evaluator needs the CLIP ViT-L/14 tokenizer from a local weights "
                f"directory; not found: {clip_dir}"
            )
        try:
            tok = CLIPTokenizer.from_pretrained(clip_dir, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise UMFError(f"cannot load a CLIP tokenizer from {clip_dir}: {exc}") from exc
        if len(tok) <= 2 or tok.eos_token_id is None or tok.bos_token_id is None:
            raise UMFError(f"broken CLIP tokenizer in {clip_dir}: {len(tok)} tokens")
        self.tokenizer, self.context = tok, context

    @property
    def vocab_size(self) -> int:
        return len(self.tokenizer)

    def encode(self, texts: list[str]) -> Tensor:
        ids = self.tokenizer(list(texts), add_special_tokens=False)["input_ids"]
        out = torch.zeros(len(ids), self.context, dtype=torch.long)
        bos, eos = self.tokenizer.bos_token_id, self.tokenizer.eos_token_id
        for i, row in enumerate(ids):
            seq = [bos, *row[: self.context - 2], eos]
            out[i, : len(seq)] = torch.tensor(seq)
        return out


def init_clip_tables(model: MotionTextEvaluator, clip_dir: str | os.PathLike | None) -> None:
    """Copy CLIP's token and position tables into a ``clip-tokens`` evaluator (training).

    InterCLIP starts from CLIP ViT-L/14's tables (the token table stays frozen); they are
    read from a local CLIP directory with ``transformers``. Missing weights are an error.
    """
    from transformers import CLIPTextModel

    from umf.text import _load_weights

    tower = model.text
    if not tower.clip_tokens:
        raise UMFError("init_clip_tables needs an evaluator built with text_encoder='clip-tokens'")
    if clip_dir is None or not Path(clip_dir).is_dir():
        raise UMFError(f"the clip-tokens evaluator needs local CLIP weights; not found: {clip_dir}")
    clip = _load_weights(CLIPTextModel, Path(clip_dir), "CLIP text model")
    emb = getattr(clip, "text_model", clip).embeddings  # transformers 4 nests it, 5 does not
    tok, pos = emb.token_embedding.weight, emb.position_embedding.weight
    if tok.shape != tower.token_embedding.weight.shape or pos.shape[-1] != tower.pos.shape[-1]:
        raise UMFError(
            f"CLIP in {clip_dir} has token table {tuple(tok.shape)}, the evaluator expects "
            f"{tuple(tower.token_embedding.weight.shape)} (text_width must equal CLIP's width)"
        )
    if pos.shape[0] < tower.pos.shape[0]:
        raise UMFError(f"CLIP in {clip_dir} has {pos.shape[0]} positions, need {CLIP_CONTEXT}")
    with torch.no_grad():
        tower.token_embedding.weight.copy_(tok)
        tower.pos.copy_(pos[: tower.pos.shape[0]])


def build_text_source(
    cfg: EvaluatorConfig, cache_dir: str | os.PathLike | None = None
) -> tuple[TextSource, dict[str, int | None]]:
    """The text source of a config and the tower sizes it implies (text_dim, vocab_size)."""
    if cfg.text_encoder == "clip-tokens":
        ids = ClipTokenIds(cfg.text_path)
        return ids, {"text_dim": None, "vocab_size": ids.vocab_size}
    from umf.text import TextFeatureCache, build_text_encoder

    enc = build_text_encoder(cfg.text_encoder, cfg.text_path, max_length=cfg.text_max_length)
    return TextFeatureCache(enc, cache_dir), {"text_dim": enc.dim, "vocab_size": None}


# --------------------------------------------------------------------- checkpoints
def evaluator_config_dict(model: MotionTextEvaluator) -> dict[str, Any]:
    """What :func:`load_evaluator` needs to rebuild ``model`` (stored as config.json)."""
    tower = model.text
    return {
        "kind": model.kind,
        "text_dim": None if tower.clip_tokens else tower.in_proj.in_features,
        "vocab_size": tower.token_embedding.num_embeddings if tower.clip_tokens else None,
        "evaluator": dataclasses.asdict(model.cfg),
    }


def load_evaluator(
    path: str | os.PathLike,
    text_source: TextSource | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> MotionTextEvaluator:
    """A trained evaluator from a checkpoint directory (or a stage dir with best/ or last/).

    The text source is rebuilt from the stored config unless given; eval mode.
    """
    from umf.checkpoint import find_checkpoint, load_checkpoint

    path = Path(path)
    if not (path / "format.json").exists():
        found = [find_checkpoint(path / s) for s in ("best", "last")]
        path = next((p for p in found if p is not None), path)
    ck = load_checkpoint(path, {})
    conf = ck.config
    if "evaluator" not in conf or "kind" not in conf:
        raise UMFError(f"{path}: not an evaluator checkpoint")
    try:
        cfg = EvaluatorConfig(**conf["evaluator"])
    except TypeError as exc:
        raise UMFError(f"{path}: evaluator config does not fit this umf ({exc})") from exc
    model = MotionTextEvaluator(cfg, conf["kind"], conf.get("text_dim"), conf.get("vocab_size"))
    load_checkpoint(path, {"evaluator": model})
    if text_source is None:
        text_source, _ = build_text_source(cfg, cache_dir)
    return model.attach_text(text_source).eval()


# --------------------------------------------------------------------- InterGen's weights
# InterGen's key (after its Lightning "model." prefix) -> ours. The layout is the one of
# InterGen's public evaluator code (InterCLIP): motion_encoder.{query_token, embed_motion,
# sequence_pos_encoder.pe, transformer.layers.N.*, out_ln, out}, token_embedding,
# positional_embedding, textTransEncoder.layers.N.*, text_ln, out, latent_scale.
INTERGEN_KEYS: tuple[tuple[str, str], ...] = (
    ("motion_encoder.query_token", "motion.query"),
    ("motion_encoder.embed_motion.", "motion.embed."),
    ("motion_encoder.transformer.", "motion.encoder."),
    ("motion_encoder.out_ln.", "motion.out_ln."),
    ("motion_encoder.out.", "motion.out."),
    ("token_embedding.", "text.token_embedding."),
    ("positional_embedding", "text.pos"),
    ("textTransEncoder.", "text.encoder."),
    ("text_ln.", "text.out_ln."),
    ("out.", "text.out."),
    ("latent_scale", "latent_scale"),
)
INTERGEN_PE = "motion_encoder.sequence_pos_encoder.pe"
INTERGEN_HEADS = 8  # not recoverable from the weights; InterGen's eval_model config


def map_intergen_keys(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Rename an InterCLIP state dict (``model.`` prefix optional) to our key names.

    The positional table (``...sequence_pos_encoder.pe``) is dropped (ours is computed);
    any key outside the assumed layout is an error.
    """
    out: dict[str, Tensor] = {}
    for raw, value in state.items():
        key = raw.removeprefix("model.")
        if key == INTERGEN_PE:
            continue
        for old, new in INTERGEN_KEYS:
            if key == old or (old.endswith(".") and key.startswith(old)):
                out[new + key[len(old) :]] = value
                break
        else:
            raise UMFError(f"unexpected key {raw!r} for InterGen's InterCLIP layout")
    return out


def _count_layers(state: Mapping[str, Tensor], prefix: str) -> int:
    idx = {int(k[len(prefix) :].split(".")[0]) for k in state if k.startswith(prefix)}
    return max(idx) + 1 if idx else 0


def intergen_config(
    state: Mapping[str, Tensor], num_heads: int = INTERGEN_HEADS
) -> EvaluatorConfig:
    """The :class:`EvaluatorConfig` whose module has the shapes of a mapped InterCLIP state."""
    need = ("motion.query", "motion.encoder.layers.0.linear1.weight", "text.out.weight",
            "text.encoder.layers.0.linear1.weight", "text.token_embedding.weight")  # fmt: skip
    for k in need:
        if k not in state:
            raise UMFError(f"InterCLIP checkpoint lacks {k} (our name); not InterGen's layout?")
    d_model = state["motion.query"].shape[-1]
    width = state["text.token_embedding.weight"].shape[-1]
    return EvaluatorConfig(
        d_model=int(d_model),
        num_layers=_count_layers(state, "motion.encoder.layers."),
        num_heads=num_heads,
        ff_dim=int(state["motion.encoder.layers.0.linear1.weight"].shape[0]),
        dropout=0.1,
        embed_dim=int(state["text.out.weight"].shape[0]),
        text_width=int(width),
        text_layers=_count_layers(state, "text.encoder.layers."),
        text_heads=num_heads,
        text_ff_dim=int(state["text.encoder.layers.0.linear1.weight"].shape[0]),
        text_encoder="clip-tokens",
        text_max_length=CLIP_CONTEXT,
        latent_scale_init=1.0,
    )


def _torch_load(path: Path, allow_pickle: bool) -> Any:
    import pickle

    try:
        return torch.load(path, map_location="cpu", weights_only=not allow_pickle)
    except (pickle.UnpicklingError, OSError, RuntimeError, EOFError, ValueError) as exc:
        text = str(exc)
        if not allow_pickle and "Unsupported global" in text:
            raise UMFError(
                f"{path}: holds Python objects besides tensors; if you trust the file, load "
                "it with allow_pickle=True"
            ) from exc
        first = (text.strip().splitlines() or [type(exc).__name__])[0]
        reason = "not a torch checkpoint" if "WeightsUnpickler" in text else first
        raise UMFError(f"{path}: cannot read checkpoint ({reason})") from exc


def load_interclip(
    path: str | os.PathLike,
    clip_dir: str | os.PathLike | None,
    *,
    kind: str = "interaction",
    allow_pickle: bool = False,
) -> MotionTextEvaluator:
    """InterGen's released evaluator (``interclip.ckpt``) as a :class:`MotionTextEvaluator`.

    Assumes InterGen's layout (:data:`INTERGEN_KEYS`): a ``torch.save`` dict whose
    ``state_dict`` (or the dict itself) holds the InterCLIP keys, optionally prefixed
    ``model.``. The sizes (1024-d 8-layer motion side, 768-d 8-layer text side, 512-d
    output in the released file) are read from the tensors; the head count is not
    stored and is InterGen's 8. ``clip_dir`` is a local CLIP ViT-L/14 directory, needed
    for its tokenizer (the token and position tables are inside InterGen's file). Missing
    or unexpected keys, a wrong shape or a tokenizer that does not fit the token table
    raise :class:`UMFError`. The input normalisation is the identity (InterGen scores
    de-normalised motions).
    """
    path = Path(path)
    if not path.is_file():
        raise UMFError(f"InterGen evaluator checkpoint not found: {path}")
    tokens = ClipTokenIds(clip_dir)
    raw = _torch_load(path, allow_pickle)
    state = raw.get("state_dict", raw) if isinstance(raw, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise UMFError(f"{path}: no tensor state_dict inside")
    mapped = map_intergen_keys(state)
    cfg = intergen_config(mapped)
    vocab = int(mapped["text.token_embedding.weight"].shape[0])
    if tokens.vocab_size != vocab:
        raise UMFError(
            f"the CLIP tokenizer in {clip_dir} has {tokens.vocab_size} tokens, the checkpoint's "
            f"token table {vocab}"
        )
    model = MotionTextEvaluator(cfg, kind, text_dim=None, vocab_size=vocab)
    _check_pe(state, model)
    own = model.state_dict()
    missing = [k for k in own if k not in mapped and k not in ("motion.in_mean", "motion.in_std")]
    unexpected = [k for k in mapped if k not in own]
    if missing or unexpected:
        what, keys = ("lacks", missing) if missing else ("has unexpected", unexpected)
        raise UMFError(f"{path}: InterCLIP checkpoint {what} {', '.join(keys[:3])} (our names)")
    for k, v in mapped.items():
        if own[k].shape != v.shape:
            raise UMFError(
                f"{path}: {k} has shape {tuple(v.shape)}, expected {tuple(own[k].shape)}"
            )
    model.load_state_dict(mapped, strict=False)
    return model.attach_text(tokens).eval()


def _check_pe(state: Mapping[str, Tensor], model: MotionTextEvaluator) -> None:
    """InterGen stores its sinusoidal table; ours must agree with it (same convention)."""
    pe = next((v for k, v in state.items() if k.removeprefix("model.") == INTERGEN_PE), None)
    if pe is None:
        return
    ours = model.motion.pe
    n = min(pe.shape[0], ours.shape[0])
    if pe.shape[-1] != ours.shape[-1] or not torch.allclose(pe[:n].float(), ours[:n], atol=1e-3):
        raise UMFError("InterCLIP checkpoint's positional table differs from the sinusoid assumed")
