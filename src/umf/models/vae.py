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
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from umf.body_frame import BODY_DIM, BODY_GROUPS, from_body_frame, to_body_frame
from umf.config import VAEConfig
from umf.representation import CONTACT, FEATURE_DIM, POS, VEL, Normalizer
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
    y_hat: Tensor | None = None  # (B, T, D) the prediction in the VAE's own space
    y: Tensor | None = None  # (B, T, D) the input in that space (the reconstruction target)


def patch_frames(x: Tensor, mask: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """(B, T, D) frames -> (B, ceil(T/k), k*D) tokens of k consecutive frames, and their
    mask (a token is valid when any of its frames is). Padding frames become zeros."""
    b, t, d = x.shape
    n = -(-t // k)
    if n * k != t:
        x = F.pad(x, (0, 0, 0, n * k - t))
        mask = F.pad(mask, (0, n * k - t), value=False)
    x = x.masked_fill(~mask[..., None], 0.0)
    return x.reshape(b, n, k * d), mask.reshape(b, n, k).any(-1)


def token_alignment(num_steps: int, frames_per_step: int, num_tokens: int, span: float) -> Tensor:
    """(num_steps, num_tokens) linear-interpolation weights between the transformer's frame
    steps and the latent tokens, latent token j standing for the frames around
    (j + 1/2) * span (absolute time: the same for every length; rows sum to 1).

    The decoder adds these mixtures of the latent tokens to its frame queries, and the
    encoder adds the frames of each token's time span to that token's query: a short path
    that makes the output vary over time from the first step, where cross-attention alone
    starts by giving every frame the same average of the latent (a frozen pose).
    """
    centre = (torch.arange(num_steps, dtype=torch.float32) + 0.5) * frames_per_step
    u = (centre / span - 0.5).clamp(0, num_tokens - 1)  # position on the token axis
    j = torch.arange(num_tokens, dtype=torch.float32)
    return (1.0 - (u[:, None] - j[None, :]).abs()).clamp_min(0.0)


def unpatch_frames(tokens: Tensor, num_frames: int, k: int) -> Tensor:
    """(B, N, k*D) tokens -> (B, num_frames, D) frames (the inverse of patch_frames)."""
    b, n, kd = tokens.shape
    return tokens.reshape(b, n * k, kd // k)[:, :num_frames]


class MotionVAE(nn.Module):
    """Multi-token motion VAE with a latent adapter (paper Sec. 4.1)."""

    def __init__(self, cfg: VAEConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d, p = cfg.d_model, cfg.num_tokens
        self.latent_dim = cfg.latent_dim if cfg.latent_adapter else d
        self.register_buffer("pos_table", sinusoidal_embedding(cfg.max_frames, d), persistent=False)
        if cfg.target not in ("body", "global"):
            raise ValueError(f"vae.target must be 'body' or 'global', got {cfg.target!r}")
        if cfg.frames_per_token < 1:
            raise ValueError(f"vae.frames_per_token must be >= 1, got {cfg.frames_per_token}")
        self.body = cfg.target == "body"
        self.space_dim = BODY_DIM if self.body else cfg.feature_dim
        k = cfg.frames_per_token
        # the statistics that map the normalised 262-d input into the VAE's own space
        # (body frame: umf.body_frame); saved with the weights, set by set_normalizers
        self.register_buffer("feature_mean", torch.zeros(FEATURE_DIM))
        self.register_buffer("feature_std", torch.ones(FEATURE_DIM))
        self.register_buffer("body_mean", torch.zeros(BODY_DIM))
        self.register_buffer("body_std", torch.ones(BODY_DIM))
        # encoder
        self.in_proj = nn.Linear(k * self.space_dim, d)
        self.query_tokens = nn.Parameter(torch.randn(2 * p, d) * 0.02)  # p mu + p logvar
        self.encoder = SkipTransformer(cfg, cross=False)
        # the latent adapter (identity in the w/o-LA ablation: the latent is d wide)
        self.adapter = nn.Linear(d, cfg.latent_dim) if cfg.latent_adapter else nn.Identity()
        # decoder
        self.latent_proj = nn.Linear(cfg.latent_dim, d) if cfg.latent_adapter else nn.Identity()
        self.token_pos = nn.Parameter(torch.randn(p, d) * 0.02)
        span = cfg.token_span or cfg.max_frames / p  # frames per latent token
        self.span = span if cfg.aligned_tokens else 0.0
        self.decoder = SkipTransformer(cfg, cross=True)
        self.out_proj = nn.Linear(d, k * self.space_dim)

    def freeze_encoder(self) -> None:
        """Hold everything that maps a motion to its latent (a decoder-only fine-tune: the
        latents the flows were trained on stay exactly what they were)."""
        for module in (self.in_proj, self.encoder, self.adapter):
            module.requires_grad_(False)
        self.query_tokens.requires_grad_(False)

    def set_normalizers(self, features: Normalizer, body: Normalizer | None = None) -> None:
        """The corpus normaliser of the 262-d input, and (body target) the body-frame one."""
        self.feature_mean.copy_(features.mean)
        self.feature_std.copy_(features.std)
        if body is not None:
            self.body_mean.copy_(body.mean)
            self.body_std.copy_(body.std)

    @torch.no_grad()
    def restate_body(self, body: Normalizer) -> None:
        """Adopt new body-frame statistics without changing what the VAE computes.

        A VAE trained on people who stand sees a crawl's pelvis height 23 standard
        deviations from its mean, further than fine-tuning at a safe learning rate can
        teach the decoder to reach. New statistics (fitted on the new corpus) put it a few
        deviations out, and the input and output projections absorb the change exactly:
        with ``y_old = a * y_new + c`` (a = s'/s, c = (m' - m)/s per dimension),
        ``in_proj`` becomes ``W diag(a)`` with bias ``b + W c`` and ``out_proj`` returns
        ``(out - c) / a``. Exact for every token whose frames are all real; a token that
        straddles the end of a clip reads its zero padding as the new mean instead of the old.
        """
        if not self.body:
            raise ValueError("restate_body needs vae.target='body'")
        k = self.cfg.frames_per_token
        a = (body.std.to(self.body_std) / self.body_std).repeat(k)
        c = ((body.mean.to(self.body_mean) - self.body_mean) / self.body_std).repeat(k)
        w = self.in_proj.weight
        self.in_proj.bias.add_(w @ c)
        w.mul_(a[None, :])
        self.out_proj.weight.div_(a[:, None])
        self.out_proj.bias.sub_(c).div_(a)
        self.body_mean.copy_(body.mean)
        self.body_std.copy_(body.std)

    def to_space(self, x: Tensor) -> Tensor:
        """Normalised 262-d features -> the normalised features the VAE models."""
        if not self.body:
            return x
        raw = x * self.feature_std + self.feature_mean
        return (to_body_frame(raw) - self.body_mean) / self.body_std

    def from_space(self, y: Tensor) -> Tensor:
        """The VAE's own normalised features -> normalised 262-d features (exact inverse)."""
        if not self.body:
            return y
        raw = from_body_frame(y * self.body_std + self.body_mean)
        return (raw - self.feature_mean) / self.feature_std

    def _alignment(self, steps: int, like: Tensor) -> Tensor:
        k, p = self.cfg.frames_per_token, self.cfg.num_tokens
        return token_alignment(steps, k, p, self.span).to(like)

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
        return self._encode_space(self._input_space(x, mask), mask)

    def _input_space(self, x: Tensor, mask: Tensor) -> Tensor:
        """Checked normalised input (padding zeroed) in the VAE's own space."""
        if x.dim() != 3 or x.shape[-1] != self.cfg.feature_dim:
            raise ValueError(f"expected x (B, T, {self.cfg.feature_dim}), got {tuple(x.shape)}")
        self._check_mask(mask, x.shape[0])
        return self.to_space(x.masked_fill(~mask[..., None], 0.0))

    def _encode_space(self, y: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        b = y.shape[0]
        # NaN/inf in padding cannot leak as 0 * nan: patch_frames zeroes padded frames
        tokens_in, token_mask = patch_frames(y, mask, self.cfg.frames_per_token)
        frames = self.in_proj(tokens_in) + self.pos_table[: tokens_in.shape[1]]
        queries = self.query_tokens.expand(b, -1, -1)
        if self.span:  # each token's query also sees the mean of its own time span
            w = self._alignment(frames.shape[1], frames) * token_mask[..., None]  # (B, N, p)
            pooled = w.transpose(1, 2) @ frames / w.sum(1)[..., None].clamp_min(1e-6)
            queries = queries + pooled.repeat(1, 2, 1)  # the mu and the logvar token
        h = torch.cat([queries, frames], dim=1)
        pad = torch.cat([mask.new_zeros(b, self.query_tokens.shape[0]), ~token_mask], dim=1)
        tokens = self.adapter(self.encoder(h, pad)[:, : self.query_tokens.shape[0]])
        mu, logvar = tokens.chunk(2, dim=1)
        return mu, logvar

    def decode(self, z: Tensor, mask: Tensor) -> Tensor:
        """z (B, p, r), mask (B, T) -> x_hat (B, T, 262); padded frames are unspecified."""
        if z.shape[1:] != self.latent_shape:
            raise ValueError(f"expected z (B, {self.latent_shape}), got {tuple(z.shape)}")
        return self.from_space(self._decode_space(z, mask))

    def _decode_space(self, z: Tensor, mask: Tensor) -> Tensor:
        self._check_mask(mask, z.shape[0])
        b, t = mask.shape
        k = self.cfg.frames_per_token
        token_mask = patch_frames(mask[..., None].float(), mask, k)[1]
        memory = self.latent_proj(z) + self.token_pos
        queries = self.pos_table[: token_mask.shape[1]].expand(b, -1, -1)
        if self.span:
            queries = queries + self._alignment(token_mask.shape[1], memory) @ memory
        return unpatch_frames(self.out_proj(self.decoder(queries, ~token_mask, memory)), t, k)

    def forward(
        self,
        x: Tensor,
        mask: Tensor,
        sample: bool = True,
        generator: torch.Generator | None = None,
    ) -> VAEOutput:
        y = self._input_space(x, mask)
        mu, logvar = self._encode_space(y, mask)
        z = reparameterize(mu, logvar, generator) if sample else mu
        y_hat = self._decode_space(z, mask)
        return VAEOutput(self.from_space(y_hat), mu, logvar, z, y_hat, y)


# --------------------------------------------------------------------- losses
def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of values (B, T, ...) over the frames where mask (B, T) is True."""
    m = mask.to(values.dtype).reshape(*mask.shape, *([1] * (values.dim() - mask.dim())))
    per_frame = values[0, 0].numel()
    return (values * m).sum() / (m.sum() * per_frame).clamp_min(1.0)


def reconstruction_loss(
    x_hat: Tensor, x: Tensor, mask: Tensor, groups: Sequence[slice] | None = None
) -> Tensor:
    """SmoothL1 on normalised features, valid frames only: the mean over all dims, or with
    ``groups`` the mean of the groups' means, so that 4 trajectory numbers weigh as much as
    126 rotation numbers (otherwise where a body is and faces is almost free to get wrong)."""
    err = F.smooth_l1_loss(x_hat, x, reduction="none")
    if groups is None:
        return masked_mean(err, mask)
    return torch.stack([masked_mean(err[..., g], mask) for g in groups]).mean()


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


def root_velocity_loss(pred: Tensor, true: Tensor, mask: Tensor, fps: float) -> Tensor:
    """Mean L1 (m/s) between the pelvis's horizontal velocity slots of raw global features
    (B, T, 262), valid frames only. The velocity slot, not the decoded path: the path is
    rebuilt mostly from these velocities (``representation.fuse_positions`` at a small
    ``root_fusion``), and the decoded absolute path jitters by centimetres every frame.
    L1, not squared: a standing person's small steady drift is what this term is for,
    and a square leaves it almost free."""
    err = (pred[..., VEL][..., [0, 2]] - true[..., VEL][..., [0, 2]]).abs().sum(-1)
    return fps * masked_mean(err, mask)


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
    fps: float = 30.0,
) -> dict[str, Tensor]:
    """Eq. 5: every enabled term (unweighted) plus their weighted sum under 'total'.

    x (B, T, 262) normalised targets, mask (B, T) valid frames. ``people`` (S, P) long
    lists the batch rows of each multi-person scene (-1 = no person in that slot); the
    interaction term needs it. A zero weight skips its term entirely. ``fps``: the
    features' frame rate (the root-velocity term is in m/s).
    """
    terms: dict[str, Tensor] = {}
    weights: dict[str, float] = {}

    def add(name: str, weight: float, fn) -> None:
        if weight != 0.0:
            terms[name], weights[name] = fn(), weight

    # in the VAE's own space (body frame: the pose slots weigh the pose, not placement)
    if out.y_hat is not None and out.y_hat.shape[-1] == BODY_DIM:
        groups = list(BODY_GROUPS.values()) if cfg.group_balanced else None
        add("recon", cfg.w_recon, lambda: reconstruction_loss(out.y_hat, out.y, mask, groups))
    else:
        add("recon", cfg.w_recon, lambda: reconstruction_loss(out.x_hat, x, mask))
    add("kl", cfg.w_kl, lambda: kl_loss(out.mu, out.logvar))
    geometric = (cfg.w_pos, cfg.w_vel, cfg.w_contact, cfg.w_bone, cfg.w_interaction, cfg.w_root_vel)
    if any(w != 0.0 for w in geometric):
        pred, true = normalizer.denormalize(out.x_hat), normalizer.denormalize(x)
        shape = (*x.shape[:2], NUM_JOINTS, 3)
        pj, tj = pred[..., POS].reshape(shape), true[..., POS].reshape(shape)
        pv, tv = pred[..., VEL].reshape(shape), true[..., VEL].reshape(shape)
        add("pos", cfg.w_pos, lambda: position_loss(pj, tj, mask))
        add("vel", cfg.w_vel, lambda: velocity_loss(pj, pv, tv, mask))
        add("contact", cfg.w_contact, lambda: foot_contact_loss(pj, tj, true[..., CONTACT], mask))
        add("bone", cfg.w_bone, lambda: bone_length_loss(pj, tj, mask))
        add("root_vel", cfg.w_root_vel, lambda: root_velocity_loss(pred, true, mask, fps))
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
