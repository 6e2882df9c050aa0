"""The flow transformer shared by P-Flow and S-Flow (SPEC 6-7).

Sequence ``[time (+ stage), text, (dataset), latent tokens]`` through a long-skip
transformer; the velocity is read off the latent positions, optionally through one output
branch per dataset. The model never sees raw text: callers pass the frozen encoder's
``TextFeatures`` (or a text token already computed by ``encode_text``, which the samplers
do once per ODE instead of once per step).
"""

from __future__ import annotations

import contextlib
import enum
import math
from collections.abc import Iterator

import torch
from torch import Tensor, nn

from umf.config import DenoiserConfig
from umf.flows.pyramid import Layout, block_size, down
from umf.text import Pooling, TextFeatures, TextHead


class _FromConfig(enum.Enum):
    VALUE = "config"


# Default of ``guidance=`` in the samplers: None must stay free to mean "no guidance".
FROM_CONFIG = _FromConfig.VALUE
GuidanceArg = float | None | _FromConfig


def resolve_guidance(guidance: GuidanceArg, default: float) -> float | None:
    """The CFG scale to use, or None for a plain conditional model (None or 1.0)."""
    scale = default if guidance is FROM_CONFIG else guidance
    return None if scale is None or float(scale) == 1.0 else float(scale)


@contextlib.contextmanager
def evaluating(module: nn.Module) -> Iterator[None]:
    """Eval mode for the duration (no dropout while sampling), then restore the old mode."""
    was = module.training
    module.train(False)
    try:
        yield
    finally:
        module.train(was)


# ----------------------------------------------------------------------- text helpers
def pad_text(text: TextFeatures, length: int) -> TextFeatures:
    """Right-pad to ``length`` tokens (zeros, mask False): the layout the encoder emits."""
    extra = length - text.tokens.shape[1]
    if extra < 0:
        raise ValueError(f"cannot pad {text.tokens.shape[1]} text tokens down to {length}")
    if extra == 0:
        return text
    tokens = nn.functional.pad(text.tokens, (0, 0, 0, extra))
    mask = nn.functional.pad(text.mask, (0, extra), value=False)
    return TextFeatures(tokens, mask, text.pooled)


def expand_text(text: TextFeatures, batch: int) -> TextFeatures:
    """Broadcast a single prompt (e.g. the empty one) to ``batch`` rows."""
    n = text.tokens.shape[0]
    if n == batch:
        return text
    if n != 1:
        raise ValueError(f"cannot expand {n} prompts to a batch of {batch}")
    return TextFeatures(
        text.tokens.expand(batch, -1, -1),
        text.mask.expand(batch, -1),
        text.pooled.expand(batch, -1),
    )


def repeat_text(text: TextFeatures, times: int) -> TextFeatures:
    """Each prompt ``times`` times in a row (several samples per prompt)."""
    if times == 1:
        return text
    return TextFeatures(
        text.tokens.repeat_interleave(times, 0),
        text.mask.repeat_interleave(times, 0),
        text.pooled.repeat_interleave(times, 0),
    )


def drop_text(text: TextFeatures, uncond_text: TextFeatures, drop: Tensor) -> TextFeatures:
    """Rows where ``drop`` (B,) is True get the unconditional prompt (CFG training).

    ``uncond_text`` is the empty prompt's features, batch B or 1; both sides are padded to
    the longer length first so the rows can be swapped.
    """
    b = text.tokens.shape[0]
    uncond_text = expand_text(uncond_text, b)
    length = max(text.tokens.shape[1], uncond_text.tokens.shape[1])
    a, u = pad_text(text, length), pad_text(uncond_text, length)
    d = drop.to(device=text.mask.device, dtype=torch.bool)
    return TextFeatures(
        torch.where(d[:, None, None], u.tokens, a.tokens),
        torch.where(d[:, None], u.mask, a.mask),
        torch.where(d[:, None], u.pooled, a.pooled),
    )


def training_text(
    net: FlowTransformer,
    p_person_drop: float,
    text: TextFeatures,
    uncond_text: TextFeatures,
    drop: Tensor,
    person_text: TextFeatures | None = None,
    person_present: Tensor | None = None,
    generator: torch.Generator | None = None,
    p_scene_drop: float = 0.0,
) -> TextFeatures | Tensor:
    """A training batch's text: rows in ``drop`` (CFG) get the empty prompt and no own
    prompt; for a model with per-person prompts, the others keep their own prompt (where
    ``person_present``) unless dropped at ``p_person_drop``, and a row that keeps it loses
    the scene prompt at ``p_scene_drop`` (the own prompt alone must then say what the person
    does). Those draws happen only for such a model (the last only when ``p_scene_drop`` >
    0), so other models see the random stream they always did."""
    scene = drop_text(text, uncond_text, drop)
    if person_text is None or net.person_proj is None:
        return scene
    d = drop.to(dtype=torch.bool)
    keep = ~d & ~(torch.rand(d.shape[0], generator=generator, device=d.device) < p_person_drop)
    if person_present is not None:
        keep = keep & person_present.to(keep.device, torch.bool)
    if p_scene_drop > 0:
        alone = keep & (torch.rand(d.shape[0], generator=generator, device=d.device) < p_scene_drop)
        scene = drop_text(text, uncond_text, d | alone)
    return net.encode_text(scene, person_text, keep)


# ----------------------------------------------------------------------- building blocks
def timestep_embedding(t: Tensor, dim: int, max_period: float = 10_000.0) -> Tensor:
    """Sinusoidal features of t in [0, 1] (scaled by 1000 so the frequencies resolve it)."""
    half = dim // 2
    freqs = torch.exp(
        -math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / half
    )
    angles = 1000.0 * t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(angles), torch.sin(angles)], dim=-1)
    return nn.functional.pad(emb, (0, dim % 2))


def encoder_layer(d: int, heads: int, ff_dim: int, dropout: float) -> nn.TransformerEncoderLayer:
    """Pre-norm GELU layer, batch first: the block every transformer here is made of."""
    return nn.TransformerEncoderLayer(
        d, heads, ff_dim, dropout, activation="gelu", batch_first=True, norm_first=True
    )


class SkipTransformer(nn.Module):
    """U-Net style long skips: L//2 in, L % 2 middle, L//2 out (exactly L layers).

    The i-th output layer first merges its input with the output of the mirrored input
    layer (Linear(2d -> d) on the concatenation), which lets early, position-level
    features reach the output directly. Returns the un-normalised residual stream.
    """

    def __init__(self, d: int, layers: int, heads: int, ff_dim: int, dropout: float):
        super().__init__()
        side = layers // 2
        self.inner = nn.ModuleList(encoder_layer(d, heads, ff_dim, dropout) for _ in range(side))
        self.middle = nn.ModuleList(
            encoder_layer(d, heads, ff_dim, dropout) for _ in range(layers - 2 * side)
        )
        self.outer = nn.ModuleList(encoder_layer(d, heads, ff_dim, dropout) for _ in range(side))
        self.merge = nn.ModuleList(nn.Linear(2 * d, d) for _ in range(side))

    def forward(self, x: Tensor, key_padding_mask: Tensor | None = None) -> Tensor:
        skips = []
        for layer in self.inner:
            x = layer(x, src_key_padding_mask=key_padding_mask)
            skips.append(x)
        for layer in self.middle:
            x = layer(x, src_key_padding_mask=key_padding_mask)
        for layer, merge in zip(self.outer, self.merge, strict=True):
            x = merge(torch.cat([x, skips.pop()], dim=-1))
            x = layer(x, src_key_padding_mask=key_padding_mask)
        return x


class OutputHead(nn.Module):
    """Optional extra layers over the whole sequence, then norm + Linear on the latents."""

    def __init__(self, d: int, out_dim: int, layers: int, heads: int, ff_dim: int, dropout: float):
        super().__init__()
        self.layers = nn.ModuleList(encoder_layer(d, heads, ff_dim, dropout) for _ in range(layers))
        self.norm = nn.LayerNorm(d)
        self.out = nn.Linear(d, out_dim)

    def forward(self, h: Tensor, prefix: int, key_padding_mask: Tensor | None) -> Tensor:
        for layer in self.layers:
            h = layer(h, src_key_padding_mask=key_padding_mask)
        return self.out(self.norm(h[:, prefix:]))


def _touch(module: nn.Module) -> Tensor:
    """A zero that depends on every parameter: keeps an idle branch in the graph for DDP."""
    return torch.stack([p.reshape(-1)[0] for p in module.parameters()]).sum() * 0.0


# ----------------------------------------------------------------------- the denoiser
class FlowTransformer(nn.Module):
    """Velocity network v(x, t, text; stage, dataset) over (B, n, in_dim) latent tokens.

    Coarse pyramid stages see the Down-pooled position embeddings of the full-resolution
    tokens (same ``layout`` as the pyramid), so a coarse token sits where the fine tokens it
    averages sit. A sample at stage k has ``num_tokens / b^(k-1)`` valid tokens first;
    inputs may be that short (sampling) or zero-padded to ``num_tokens`` (training), and
    padded tokens are masked out of attention.
    """

    def __init__(
        self,
        cfg: DenoiserConfig,
        in_dim: int,
        out_dim: int,
        text_dim: int,
        num_tokens: int,
        num_stages: int = 1,
        num_datasets: int = 0,
        text_pool: Pooling = "mean",
        *,
        layout: Layout = "1d",
        latent_cond_dim: int = 0,
    ):
        super().__init__()
        if num_stages < 1 or num_datasets < 0:
            raise ValueError(f"bad num_stages={num_stages} / num_datasets={num_datasets}")
        d = cfg.d_model
        self.in_dim, self.out_dim, self.d_model = in_dim, out_dim, d
        self.num_tokens, self.num_stages, self.num_datasets = num_tokens, num_stages, num_datasets
        self.layout: Layout = layout
        self.block = block_size(layout)
        if num_tokens % self.block ** (num_stages - 1):
            raise ValueError(f"{num_tokens} tokens cannot be pooled {num_stages - 1} times")

        self.in_proj = nn.Linear(in_dim, d)
        # a per-token condition beside the state (the S-Flow's clean context), added to each
        # latent token; zero at first, so a model fine-tuned with it starts as it was
        self.cond_proj = nn.Linear(latent_cond_dim, d) if latent_cond_dim else None
        if self.cond_proj is not None:
            nn.init.zeros_(self.cond_proj.weight)
            nn.init.zeros_(self.cond_proj.bias)
        self.pos = nn.Parameter(torch.empty(num_tokens, d))
        self.time_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        self.stage_emb = nn.Embedding(num_stages, d) if num_stages > 1 else None
        self.dataset_emb = nn.Embedding(num_datasets, d) if num_datasets > 0 else None

        def text_head() -> TextHead:
            return TextHead(text_dim, d, width=cfg.text_width, heads=cfg.text_heads,
                            ff_dim=cfg.text_ff_dim, layers=cfg.text_layers, pool=text_pool,
                            dropout=cfg.dropout)  # fmt: skip

        self.text_head = text_head()
        self.backbone = SkipTransformer(d, cfg.num_layers, cfg.num_heads, cfg.ff_dim, cfg.dropout)
        branch_layers = cfg.branch_layers if num_datasets > 0 else 0
        self.heads = nn.ModuleList(
            OutputHead(d, out_dim, branch_layers, cfg.num_heads, cfg.ff_dim, cfg.dropout)
            for _ in range(max(1, num_datasets))
        )
        self.prefix = 2 + (num_datasets > 0)
        # per-person prompts: zero at first, so a model fine-tuned with them starts as it was
        if cfg.person_head and not cfg.person_text:
            raise ValueError("denoiser.person_head needs denoiser.person_text")
        self.person_proj = nn.Linear(d, d) if cfg.person_text else None
        self.person_head = text_head() if cfg.person_head else None
        if self.person_proj is not None:
            nn.init.zeros_(self.person_proj.weight)
            nn.init.zeros_(self.person_proj.bias)
        nn.init.trunc_normal_(self.pos, std=0.02)
        for emb in (self.stage_emb, self.dataset_emb):
            if emb is not None:
                nn.init.trunc_normal_(emb.weight, std=0.02)

    # ------------------------------------------------------------------ pieces
    def tokens_at(self, stage: Tensor) -> Tensor:
        """Valid token count per sample at pyramid ``stage`` (1 = full resolution)."""
        return torch.div(self.num_tokens, self.block ** (stage - 1), rounding_mode="floor")

    def positions(self) -> Tensor:
        """(K, p, d) position table: row k-1 = Down^(k-1) of the fine ones, zero-padded."""
        rows = [self.pos]
        for level in range(1, self.num_stages):
            coarse = down(self.pos[None], self.layout, level)[0]
            rows.append(nn.functional.pad(coarse, (0, 0, 0, self.num_tokens - coarse.shape[0])))
        return torch.stack(rows)

    def encode_text(
        self,
        text: TextFeatures,
        person: TextFeatures | None = None,
        person_present: Tensor | None = None,
    ) -> Tensor:
        """(B, d) text token; constant along an ODE, so samplers compute it once.

        ``person``: each row's own prompt (per-person prompts), added as
        :meth:`person_token`.
        """
        cond = self.text_head(text.tokens, text.mask)
        if person is None:
            return cond
        return cond + self.person_token(person, cond.shape[0], person_present)

    def person_token(
        self, person: TextFeatures, batch: int, person_present: Tensor | None = None
    ) -> Tensor:
        """(B, d) own-prompt part of the text token: the own prompt through the text head
        (its own with ``person_head``, else the scene's) and ``person_proj``;
        ``person_present`` (B,) bool zeroes the rows without one."""
        if self.person_proj is None:
            raise ValueError("this model was not trained with per-person prompts")
        person = expand_text(person, batch)
        head = self.text_head if self.person_head is None else self.person_head
        own = self.person_proj(head(person.tokens, person.mask))
        if person_present is not None:
            own = own * person_present.to(device=own.device, dtype=own.dtype)[:, None]
        return own

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        x: Tensor,
        t: Tensor,
        text: TextFeatures | Tensor,
        *,
        stage: Tensor | None = None,
        dataset: Tensor | None = None,
        token_mask: Tensor | None = None,
        latent_cond: Tensor | None = None,
    ) -> Tensor:
        """x (B, n, in_dim), t (B,) global time -> velocity (B, n, out_dim).

        ``latent_cond`` (B, n, latent_cond_dim): a per-token condition, required exactly
        when the model was built with ``latent_cond_dim``.
        ``stage`` (B,) long in [1, K] (None: full resolution); ``dataset`` (B,) long,
        required when the model has dataset tokens; ``token_mask`` (B, n) True at valid
        tokens (None: the first ``tokens_at(stage)`` tokens). ``text`` is TextFeatures or a
        precomputed ``encode_text`` token.
        """
        b, n, _ = x.shape
        if n > self.num_tokens:
            raise ValueError(f"{n} tokens > num_tokens {self.num_tokens}")
        if stage is None:
            stage = torch.ones(b, dtype=torch.long, device=x.device)
        stage = stage.to(device=x.device, dtype=torch.long)
        count = self.tokens_at(stage)
        if bool((count > n).any()):
            raise ValueError(f"{n} tokens are fewer than a stage of this batch needs")
        if token_mask is None:
            token_mask = torch.arange(n, device=x.device)[None] < count[:, None]

        time = self.time_mlp(timestep_embedding(t, self.d_model).to(x.dtype))
        if self.stage_emb is not None:
            time = time + self.stage_emb(stage - 1)
        cond = self.encode_text(text) if isinstance(text, TextFeatures) else text
        prefix = [time, cond.expand(b, -1)]
        if self.dataset_emb is not None:
            if dataset is None:
                raise ValueError("this model has dataset tokens: pass dataset=(B,) long")
            dataset = dataset.to(device=x.device, dtype=torch.long)
            prefix.append(self.dataset_emb(dataset))
        latents = self.in_proj(x) + self.positions()[stage - 1, :n]
        if (self.cond_proj is None) != (latent_cond is None):
            raise ValueError("pass latent_cond exactly when the model has a latent condition")
        if self.cond_proj is not None:
            latents = latents + self.cond_proj(latent_cond)
        h = torch.cat([torch.stack(prefix, 1), latents], dim=1)

        kpm = None
        if not bool(token_mask.all()):
            valid = torch.cat([token_mask.new_ones(b, self.prefix), token_mask.bool()], dim=1)
            kpm = ~valid
        h = self.backbone(h, kpm)
        return self._heads(h, kpm, dataset)

    def _heads(self, h: Tensor, kpm: Tensor | None, dataset: Tensor | None) -> Tensor:
        """Per-sample dataset branch; only the samples that choose a branch run through it."""
        if len(self.heads) == 1:
            return self.heads[0](h, self.prefix, kpm)
        assert dataset is not None
        out = h.new_zeros(h.shape[0], h.shape[1] - self.prefix, self.out_dim)
        for i, head in enumerate(self.heads):
            idx = (dataset == i).nonzero().squeeze(1)
            if idx.numel():
                sub_kpm = None if kpm is None else kpm[idx]
                out = out.index_copy(0, idx, head(h[idx], self.prefix, sub_kpm))
            elif torch.is_grad_enabled():
                out = out + _touch(head)
        return out
