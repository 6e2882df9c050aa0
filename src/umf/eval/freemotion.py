"""A FreeMotion-class generator, built to be timed against UMF (issue 36).

The paper's speed claim (UMF about 5x faster than FreeMotion at 60 steps, Table 4) is a
claim about work per scene, which does not depend on trained weights. This module builds
that work from FreeMotion's published configuration (SPEC 8): a transformer over raw
per-person frames (262-d InterHuman features, no latent space), 8 layers 1024 wide with 8
heads and a 2048 feed-forward, text read by cross-attention; DDIM with 50 steps and
classifier-free guidance (conditional and unconditional halves in one batch); each added
person through a ControlNet-style copy of the transformer that reads the people generated
before, its outputs joined to the main stream by zero-initialised projections.

Weights are random: the samples are noise-shaped, only their cost is meaningful.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass
class FreeMotionConfig:
    """FreeMotion's published size (defaults) or any other for comparison."""

    feature_dim: int = 262  # InterHuman's per-person frame
    dim: int = 1024
    num_layers: int = 8
    num_heads: int = 8
    ff_dim: int = 2048
    text_dim: int = 768  # CLIP ViT-L token width
    train_steps: int = 1000  # the DDPM schedule the 50 DDIM steps subsample
    steps: int = 50
    guidance: float = 3.5


def _layer(cfg: FreeMotionConfig) -> nn.TransformerDecoderLayer:
    """Self-attention over frames, cross-attention to the text tokens, feed-forward."""
    return nn.TransformerDecoderLayer(cfg.dim, cfg.num_heads, cfg.ff_dim, 0.0, activation="gelu",
                                      batch_first=True, norm_first=True)  # fmt: skip


def timestep_embedding(t: Tensor, dim: int) -> Tensor:
    """Sinusoidal embedding (B, dim) of integer diffusion steps ``t`` (B,)."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs.to(t.device)[None]
    return torch.cat([torch.cos(args), torch.sin(args)], dim=-1)


class FreeMotionNet(nn.Module):
    """x0-predicting denoiser over (B, T, feature_dim) frames; with ``others`` (B, K, T,
    feature_dim), the people generated before, its ControlNet branch runs as well."""

    def __init__(self, cfg: FreeMotionConfig, max_frames: int = 300):
        super().__init__()
        self.cfg = cfg
        d = cfg.dim
        self.motion_in = nn.Linear(cfg.feature_dim, d)
        self.text_in = nn.Linear(cfg.text_dim, d)
        self.time_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        self.pos = nn.Parameter(torch.randn(1, max_frames, d) * 0.02)
        self.layers = nn.ModuleList(_layer(cfg) for _ in range(cfg.num_layers))
        self.out = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, cfg.feature_dim))
        # the interaction module: a trainable copy reading the others, joined by zero convs
        self.control_in = nn.Linear(cfg.feature_dim, d)
        self.control = nn.ModuleList(_layer(cfg) for _ in range(cfg.num_layers))
        self.zero = nn.ModuleList(nn.Linear(d, d) for _ in range(cfg.num_layers))
        for z in self.zero:
            nn.init.zeros_(z.weight)
            nn.init.zeros_(z.bias)

    def forward(self, x: Tensor, t: Tensor, text: Tensor, others: Tensor | None = None) -> Tensor:
        frames = x.shape[1]
        cond = self.time_mlp(timestep_embedding(t, self.cfg.dim))[:, None]
        memory = self.text_in(text)
        h = self.motion_in(x) + self.pos[:, :frames] + cond
        c = None
        if others is not None:
            c = h + self.control_in(others).mean(dim=1)
        for k, layer in enumerate(self.layers):
            if c is not None:
                c = self.control[k](c, memory)
                h = layer(h, memory) + self.zero[k](c)
            else:
                h = layer(h, memory)
        return self.out(h)


def ddim_alphas(cfg: FreeMotionConfig) -> tuple[Tensor, Tensor]:
    """(steps,) training steps visited, noisiest first, and the cumulative alphas (train_steps,)
    of the cosine schedule (Nichol & Dhariwal), as InterGen and FreeMotion use."""
    s = 0.008
    grid = torch.arange(cfg.train_steps + 1, dtype=torch.float64) / cfg.train_steps
    f = torch.cos((grid + s) / (1 + s) * math.pi / 2) ** 2
    betas = (1 - f[1:] / f[:-1]).clamp(max=0.999)
    alphas_bar = torch.cumprod(1 - betas, dim=0)
    stride = cfg.train_steps // cfg.steps
    visited = torch.arange(0, cfg.train_steps, stride).flip(0)
    return visited, alphas_bar


def ddim_step(x: Tensor, x0: Tensor, a_t: float, a_prev: float) -> Tensor:
    """Deterministic DDIM update (eta 0) from step t to the next visited one, given the
    network's clean estimate ``x0``: re-noise x0 with the noise x implies."""
    eps = (x - math.sqrt(a_t) * x0) / math.sqrt(1 - a_t)
    return math.sqrt(a_prev) * x0 + math.sqrt(1 - a_prev) * eps


@torch.inference_mode()
def sample_person(net: FreeMotionNet, text: Tensor, uncond: Tensor, frames: int,
                  others: Tensor | None = None, generator: torch.Generator | None = None
                  ) -> tuple[Tensor, int]:  # fmt: skip
    """One person (B, frames, feature_dim) by DDIM with CFG; returns it and the network
    evaluations (one per step: the guided pair runs as one batch)."""
    cfg = net.cfg
    b = text.shape[0]
    visited, alphas_bar = ddim_alphas(cfg)
    x = torch.randn(b, frames, cfg.feature_dim, generator=generator)
    both_text = torch.cat([text, uncond])
    both_others = None if others is None else torch.cat([others, others])
    for i, t in enumerate(visited.tolist()):
        steps = torch.full((2 * b,), t, dtype=torch.long)
        cond, free = net(torch.cat([x, x]), steps, both_text, both_others).chunk(2)
        x0 = free + cfg.guidance * (cond - free)
        a_prev = float(alphas_bar[visited[i + 1]]) if i + 1 < len(visited) else 1.0
        x = ddim_step(x, x0, float(alphas_bar[t]), a_prev)
    return x, len(visited)


def sample_scene(
    net: FreeMotionNet,
    text: Tensor,
    uncond: Tensor,
    num_people: int,
    frames: int,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, int]:
    """(B, num_people, frames, feature_dim): person 1 alone, then each further person with
    everyone before as the ControlNet branch's input; returns it and the evaluations."""
    people, nfe = [], 0
    for _ in range(num_people):
        others = torch.stack(people, dim=1) if people else None
        x, n = sample_person(net, text, uncond, frames, others, generator)
        people.append(x)
        nfe += n
    return torch.stack(people, dim=1), nfe
