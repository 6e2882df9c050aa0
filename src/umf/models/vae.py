"""The motion VAE of UMF (paper Sec. 4.1, SPEC section 3).

One VAE for every person. A motion (B, T, 262) of normalised features becomes a latent
z (B, p, r) of p tokens: the encoder prepends 2p learned query tokens to the frames and
reads mu and logvar off their outputs; the *latent adapter* Linear(d -> r) then squeezes
the wide internal tokens into the compact space the flows work in. The decoder expands
z back with Linear(r -> d) and lets T frame queries (positional embeddings) cross-attend
to it. Both sides are long-skip ("U-Net") transformers. Padded frames are masked out of
every attention, so they never influence the latent or the valid output frames.

The losses are small pure functions: reconstruction + KL + the geometric terms of
Eq. 5 (positions, velocities, foot contacts, bone lengths, and an interaction distance
map for scenes of several people), all restricted to valid frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from umf.config import VAEConfig
from umf.representation import CONTACT, POS, VEL, Normalizer
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT, NUM_JOINTS, bone_lengths

Tensor = torch.Tensor

FOOT_JOINTS = (*FOOT_LEFT, *FOOT_RIGHT)  # same order as the contact slots
NEAR_DISTANCE = 1.0  # metres: joint pairs closer than this drive the interaction loss


# --------------------------------------------------------------------- helpers
def sinusoidal_embedding(length: int, dim: int) -> Tensor:
    """Fixed (length, dim) sin/cos table: no parameters, defined for every T <= length."""
    pos = torch.arange(length, dtype=torch.float32)[:, None]
    freq = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10_000.0) / dim))
    table = torch.zeros(length, dim)
    table[:, 0::2] = torch.sin(pos * freq)
    table[:, 1::2] = torch.cos(pos * freq[: dim // 2])
    return table


def count_parameters(module: nn.Module, trainable_only: bool = False) -> int:
    """Number of scalar parameters (all, or only those with requires_grad)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)


def reparameterize(mu: Tensor, logvar: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """z = mu + sigma * eps; the explicit generator makes sampling reproducible."""
    eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
    return mu + torch.exp(0.5 * logvar) * eps


# --------------------------------------------------------------------- backbone
class SkipTransformer(nn.Module):
    """L//2 'in' blocks, 1 middle, L//2 'out' blocks; out block k also sees in block
    L//2 - 1 - k's output (concatenated, merged by Linear(2d -> d)).

    The long skips give the deep stack a short gradient path, as in a U-Net. With
    ``cross=True`` the blocks are decoder layers that also attend to a memory. An even
    ``num_layers`` builds L + 1 blocks (the middle block is always there).
    """

    def __init__(self, cfg: VAEConfig, cross: bool) -> None:
        super().__init__()
        d, half = cfg.d_model, cfg.num_layers // 2
        layer_cls = nn.TransformerDecoderLayer if cross else nn.TransformerEncoderLayer

        def block() -> nn.Module:
            return layer_cls(
                d, cfg.num_heads, cfg.ff_dim, cfg.dropout, activation="gelu",
                batch_first=True, norm_first=True,
            )  # fmt: skip

        self.cross = cross
        self.blocks_in = nn.ModuleList(block() for _ in range(half))
        self.middle = block()
        self.blocks_out = nn.ModuleList(block() for _ in range(half))
        self.merges = nn.ModuleList(nn.Linear(2 * d, d) for _ in range(half))
        self.norm = nn.LayerNorm(d)  # pre-norm blocks leave the residual stream unnormalised

    def _block(self, block: nn.Module, h: Tensor, pad: Tensor, memory: Tensor | None) -> Tensor:
        if self.cross:
            return block(h, memory, tgt_key_padding_mask=pad)
        return block(h, src_key_padding_mask=pad)

    def forward(self, h: Tensor, pad: Tensor, memory: Tensor | None = None) -> Tensor:
        """h (B, N, d); pad (B, N) bool, True = padding (ignored as attention key)."""
        skips = []
        for block in self.blocks_in:
            h = self._block(block, h, pad, memory)
            skips.append(h)
        h = self._block(self.middle, h, pad, memory)
        for block, merge in zip(self.blocks_out, self.merges, strict=True):
            h = self._block(block, merge(torch.cat([h, skips.pop()], dim=-1)), pad, memory)
        return self.norm(h)


# --------------------------------------------------------------------- the VAE
@dataclass
class VAEOutput:
    x_hat: Tensor  # (B, T, 262) normalised reconstruction
    mu: Tensor  # (B, p, r)
    logvar: Tensor  # (B, p, r)
    z: Tensor  # (B, p, r) the latent that was decoded


class MotionVAE(nn.Module):
    """Multi-token motion VAE with a latent adapter (paper Sec. 4.1)."""

    def __init__(self, cfg: VAEConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d, p = cfg.d_model, cfg.num_tokens
        self.latent_dim = cfg.latent_dim if cfg.latent_adapter else d
        self.register_buffer("pos_table", sinusoidal_embedding(cfg.max_frames, d), persistent=False)
        # encoder
        self.in_proj = nn.Linear(cfg.feature_dim, d)
        self.query_tokens = nn.Parameter(torch.randn(2 * p, d) * 0.02)  # p mu + p logvar
        self.encoder = SkipTransformer(cfg, cross=False)
        # the latent adapter (identity in the w/o-LA ablation: the latent is d wide)
        self.adapter = nn.Linear(d, cfg.latent_dim) if cfg.latent_adapter else nn.Identity()
        # decoder
        self.latent_proj = nn.Linear(cfg.latent_dim, d) if cfg.latent_adapter else nn.Identity()
        self.token_pos = nn.Parameter(torch.randn(p, d) * 0.02)
        self.decoder = SkipTransformer(cfg, cross=True)
        self.out_proj = nn.Linear(d, cfg.feature_dim)

    @property
    def latent_shape(self) -> tuple[int, int]:
        return self.cfg.num_tokens, self.latent_dim

    def _check_mask(self, mask: Tensor, batch: int | None = None) -> None:
        if mask.dim() != 2 or mask.dtype != torch.bool:
            raise ValueError(f"mask must be (B, T) bool, got {tuple(mask.shape)} {mask.dtype}")
        if batch is not None and mask.shape[0] != batch:
            raise ValueError(f"mask batch {mask.shape[0]} does not match {batch}")
        if mask.shape[1] > self.cfg.max_frames:
            raise ValueError(
                f"{mask.shape[1]} frames exceed the VAE's max_frames={self.cfg.max_frames}"
            )
        if not bool(mask.any(dim=1).all()):
            raise ValueError("every sequence needs at least one valid frame")

    def encode(self, x: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        """x (B, T, 262) normalised, mask (B, T) True = valid -> mu, logvar (B, p, r)."""
        if x.dim() != 3 or x.shape[-1] != self.cfg.feature_dim:
            raise ValueError(f"expected x (B, T, {self.cfg.feature_dim}), got {tuple(x.shape)}")
        self._check_mask(mask, x.shape[0])
        b, t, _ = x.shape
        x = x.masked_fill(~mask[..., None], 0.0)  # NaN/inf in padding cannot leak as 0 * nan
        frames = self.in_proj(x) + self.pos_table[:t]
        h = torch.cat([self.query_tokens.expand(b, -1, -1), frames], dim=1)
        pad = torch.cat([mask.new_zeros(b, self.query_tokens.shape[0]), ~mask], dim=1)
        tokens = self.adapter(self.encoder(h, pad)[:, : self.query_tokens.shape[0]])
        mu, logvar = tokens.chunk(2, dim=1)
        return mu, logvar

    def decode(self, z: Tensor, mask: Tensor) -> Tensor:
        """z (B, p, r), mask (B, T) -> x_hat (B, T, 262); padded frames are unspecified."""
        if z.shape[1:] != self.latent_shape:
            raise ValueError(f"expected z (B, {self.latent_shape}), got {tuple(z.shape)}")
        self._check_mask(mask, z.shape[0])
        b, t = mask.shape
        memory = self.latent_proj(z) + self.token_pos
        queries = self.pos_table[:t].expand(b, -1, -1)
        return self.out_proj(self.decoder(queries, ~mask, memory))

    def forward(
        self,
        x: Tensor,
        mask: Tensor,
        sample: bool = True,
        generator: torch.Generator | None = None,
    ) -> VAEOutput:
        mu, logvar = self.encode(x, mask)
        z = reparameterize(mu, logvar, generator) if sample else mu
        return VAEOutput(self.decode(z, mask), mu, logvar, z)


# --------------------------------------------------------------------- losses
def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of values (B, T, ...) over the frames where mask (B, T) is True."""
    m = mask.to(values.dtype).reshape(*mask.shape, *([1] * (values.dim() - mask.dim())))
    per_frame = values[0, 0].numel()
    return (values * m).sum() / (m.sum() * per_frame).clamp_min(1.0)


def reconstruction_loss(x_hat: Tensor, x: Tensor, mask: Tensor) -> Tensor:
    """SmoothL1 on normalised features, all 262 dims, valid frames only."""
    return masked_mean(F.smooth_l1_loss(x_hat, x, reduction="none"), mask)


def kl_loss(mu: Tensor, logvar: Tensor) -> Tensor:
    """KL(N(mu, sigma^2) || N(0, I)), averaged over latent elements."""
    return (0.5 * (mu.pow(2) + logvar.exp() - 1.0 - logvar)).mean()


def pair_mask(mask: Tensor) -> Tensor:
    """(B, T - 1): frame t and t + 1 are both valid, so their difference is real."""
    return mask[:, 1:] & mask[:, :-1]


def position_loss(pred: Tensor, true: Tensor, mask: Tensor) -> Tensor:
    """L1 between joints (B, T, 22, 3) in metres."""
    return masked_mean((pred - true).abs(), mask)


def velocity_loss(pred_joints: Tensor, pred_vel: Tensor, true_vel: Tensor, mask: Tensor) -> Tensor:
    """Velocity slots vs truth, plus the finite difference of the predicted joints vs
    the true velocities: the two ways of reading motion must agree with the data."""
    slots = masked_mean((pred_vel - true_vel).abs(), mask)
    diff = pred_joints[:, 1:] - pred_joints[:, :-1]
    return 0.5 * (slots + masked_mean((diff - true_vel[:, :-1]).abs(), pair_mask(mask)))


def foot_contact_loss(
    pred_joints: Tensor, true_joints: Tensor, contacts: Tensor, mask: Tensor
) -> Tensor:
    """Foot sliding: where the truth says a foot is planted, its predicted speed may not
    exceed the true speed (a one-sided hinge, m/frame, averaged over planted feet).

    The contact rule tolerates up to ~3 cm/frame, so asking for zero speed would fight
    the data; the hinge only removes sliding the ground truth does not have.
    """
    feet = list(FOOT_JOINTS)

    def speed(j: Tensor) -> Tensor:
        return (j[:, 1:, feet] - j[:, :-1, feet]).pow(2).sum(-1).add(1e-12).sqrt()

    excess = F.relu(speed(pred_joints) - speed(true_joints))  # (B, T - 1, 4)
    weight = contacts[:, :-1] * pair_mask(mask)[..., None].to(contacts.dtype)
    return (excess * weight).sum() / weight.sum().clamp_min(1.0)


def bone_length_loss(pred: Tensor, true: Tensor, mask: Tensor) -> Tensor:
    """L1 between per-frame bone lengths (21 bones, metres)."""
    return masked_mean((bone_lengths(pred) - bone_lengths(true))[..., 1:].abs(), mask)


def joint_distance_map(a: Tensor, b: Tensor) -> Tensor:
    """Distances (..., 22, 22) between every joint of a (..., 22, 3) and of b."""
    return (a[..., :, None, :] - b[..., None, :, :]).pow(2).sum(-1).add(1e-12).sqrt()


def interaction_loss(
    pred: Tensor,
    true: Tensor,
    mask: Tensor,
    person_mask: Tensor | None = None,
    near: float = NEAR_DISTANCE,
) -> Tensor:
    """InterGen-style distance-map loss between people of a scene.

    pred, true (S, P, T, 22, 3) metres; mask (S, T) valid frames; person_mask (S, P)
    marks real people (scenes of fewer than P). For every pair a < b, the 22 x 22
    joint distances of the prediction are compared (L1) with the truth's. Only
    entries that are near (< ``near`` m) in the truth *or* in the prediction count:
    contacts and close approaches carry the interaction, the exact gap between far
    joints does not, and joints that the prediction brings falsely close are still
    penalised. Averaged over the counted entries.
    """
    s, p = pred.shape[:2]
    if person_mask is None:
        person_mask = torch.ones(s, p, dtype=torch.bool, device=pred.device)
    total = pred.new_zeros(())
    count = pred.new_zeros(())
    for a in range(p):
        for b in range(a + 1, p):
            d_pred = joint_distance_map(pred[:, a], pred[:, b])  # (S, T, 22, 22)
            d_true = joint_distance_map(true[:, a], true[:, b])
            valid = mask & person_mask[:, a, None] & person_mask[:, b, None]  # (S, T)
            sel = ((d_true < near) | (d_pred.detach() < near)) & valid[..., None, None]
            sel = sel.to(pred.dtype)
            total = total + ((d_pred - d_true).abs() * sel).sum()
            count = count + sel.sum()
    return total / count.clamp_min(1.0)


def vae_losses(
    out: VAEOutput,
    x: Tensor,
    mask: Tensor,
    normalizer: Normalizer,
    cfg: VAEConfig,
    people: Tensor | None = None,
) -> dict[str, Tensor]:
    """Eq. 5: every enabled term (unweighted) plus their weighted sum under 'total'.

    x (B, T, 262) normalised targets, mask (B, T) valid frames. ``people`` (S, P) long
    lists the batch rows of each multi-person scene (-1 = no person in that slot); the
    interaction term needs it. A zero weight skips its term entirely.
    """
    terms: dict[str, Tensor] = {}
    weights: dict[str, float] = {}

    def add(name: str, weight: float, fn) -> None:
        if weight != 0.0:
            terms[name], weights[name] = fn(), weight

    add("recon", cfg.w_recon, lambda: reconstruction_loss(out.x_hat, x, mask))
    add("kl", cfg.w_kl, lambda: kl_loss(out.mu, out.logvar))
    geometric = (cfg.w_pos, cfg.w_vel, cfg.w_contact, cfg.w_bone, cfg.w_interaction)
    if any(w != 0.0 for w in geometric):
        pred, true = normalizer.denormalize(out.x_hat), normalizer.denormalize(x)
        shape = (*x.shape[:2], NUM_JOINTS, 3)
        pj, tj = pred[..., POS].reshape(shape), true[..., POS].reshape(shape)
        pv, tv = pred[..., VEL].reshape(shape), true[..., VEL].reshape(shape)
        add("pos", cfg.w_pos, lambda: position_loss(pj, tj, mask))
        add("vel", cfg.w_vel, lambda: velocity_loss(pj, pv, tv, mask))
        add("contact", cfg.w_contact, lambda: foot_contact_loss(pj, tj, true[..., CONTACT], mask))
        add("bone", cfg.w_bone, lambda: bone_length_loss(pj, tj, mask))
        if people is not None and people.shape[1] > 1:
            rows = people.clamp_min(0)
            present = people >= 0
            scene_mask = (mask[rows] | ~present[..., None]).all(dim=1)  # frames all share
            add(
                "interaction",
                cfg.w_interaction,
                lambda: interaction_loss(pj[rows], tj[rows], scene_mask, present),
            )
    terms["total"] = sum((weights[k] * v for k, v in terms.items()), x.new_zeros(()))
    return terms
