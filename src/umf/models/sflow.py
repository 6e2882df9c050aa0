"""S-Flow: the next person's latent from the previous ones (paper Sec. 4.2.2, SPEC 7).

The context adapter turns the previous people's latents into C; a flow transformer
integrates the semi-noise joint state [eps || C] -> [C || W] once (``umf.flows.semi_noise``
holds the path, loss and sampler). Training feeds the adapter the latents of the real
preceding people (never P-Flow velocities, SPEC 7 (a)); ``context_noise`` optionally
perturbs them so real contexts look more like the imperfect generated ones seen at
inference.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor, nn

from umf.config import MULTI_PERSON, SFlowConfig
from umf.flows import (
    Method,
    classifier_free_guidance,
    composed_guidance,
    reaction_endpoint,
    sample_semi_noise,
    semi_noise_loss,
    semi_noise_training_sample,
)
from umf.flows.noise import Generators
from umf.models.context import ContextAdapter
from umf.models.denoiser import (
    FROM_CONFIG,
    FlowTransformer,
    GuidanceArg,
    evaluating,
    resolve_guidance,
    training_text,
)
from umf.models.latent_normalizer import LatentNormalizer
from umf.models.pflow import encode_uncond
from umf.text import Pooling, TextFeatures


class SFlow(nn.Module):
    """Context adapter + semi-noise flow transformer (K = 1, no dataset token).

    The state is (B, p, 2r) (context half || reaction half), or (B, p, r) for the
    ``reaction_only`` ablation. With ``cfg.shared_backbone`` the given P-Flow transformer
    is reused (registered here too, so its weights are also in this module's state) behind
    Linear adapters state -> r -> state, at full resolution with the multi-person token.
    ``forward`` is ``loss`` (for DDP).
    """

    def __init__(
        self,
        cfg: SFlowConfig,
        num_tokens: int,
        latent_dim: int,
        text_dim: int,
        backbone: FlowTransformer | None = None,
        *,
        text_pool: Pooling = "mean",
    ):
        super().__init__()
        self.cfg = cfg
        self.num_tokens, self.latent_dim = num_tokens, latent_dim
        self.state_dim = latent_dim if cfg.reaction_only else 2 * latent_dim
        self.latent_norm = LatentNormalizer(num_tokens, latent_dim)  # fit by the stage
        self.context = ContextAdapter(
            latent_dim,
            cfg.context_heads,
            cfg.context_ff_dim,
            cfg.context_layers,
            positional=cfg.context_positional,
            enabled=cfg.context_adapter,
            num_tokens=num_tokens,
            dropout=cfg.denoiser.dropout,
        )
        self.in_adapter: nn.Linear | None = None
        self.out_adapter: nn.Linear | None = None
        if cfg.shared_backbone != (backbone is not None):
            raise ValueError("pass the P-Flow backbone exactly when cfg.shared_backbone is set")
        if backbone is not None and cfg.context_condition:
            raise ValueError("sflow.context_condition needs the S-Flow's own transformer")
        if backbone is not None:
            if backbone.num_tokens != num_tokens:
                raise ValueError(f"backbone has {backbone.num_tokens} tokens, not {num_tokens}")
            self.net = backbone
            self.in_adapter = nn.Linear(self.state_dim, backbone.in_dim)
            self.out_adapter = nn.Linear(backbone.out_dim, self.state_dim)
        else:
            self.net = FlowTransformer(
                cfg.denoiser,
                self.state_dim,
                self.state_dim,
                text_dim,
                num_tokens,
                num_stages=1,
                num_datasets=0,
                text_pool=text_pool,
                latent_cond_dim=latent_dim if cfg.context_condition else 0,
            )

    def forward(self, *args: Any, **kwargs: Any) -> dict[str, Tensor]:
        return self.loss(*args, **kwargs)

    def velocity(
        self, x: Tensor, t: Tensor, text: TextFeatures | Tensor, context: Tensor | None = None
    ) -> Tensor:
        """Velocity of the joint state x (B, p, state_dim) at time t (B,); ``context`` (B, p,
        r), the adapter's C, is read by a model with ``context_condition`` (and needed)."""
        if self.in_adapter is None or self.out_adapter is None:
            cond = context if self.cfg.context_condition else None
            if self.cfg.context_condition and context is None:
                raise ValueError("this S-Flow reads the context beside the state: pass context")
            return self.net(x, t, text, latent_cond=cond)
        kw: dict[str, Tensor] = {}
        if self.net.num_datasets > 0:
            index = min(MULTI_PERSON, self.net.num_datasets - 1)
            kw["dataset"] = torch.full((x.shape[0],), index, device=x.device)
        return self.out_adapter(self.net(self.in_adapter(x), t, text, **kw))

    def perturb_context(
        self, prev: Tensor, prev_mask: Tensor, generator: torch.Generator | None = None
    ) -> Tensor:
        """prev + context_noise * std * N(0, 1), std per (token, channel) over the batch's
        real previous people (a scale-free noise level whatever the VAE's latent scale)."""
        real = prev[prev_mask.bool()]
        if self.cfg.context_noise <= 0 or real.shape[0] < 2:
            return prev
        std = real.detach().std(dim=0, correction=0)
        noise = torch.randn(prev.shape, generator=generator, device=prev.device, dtype=prev.dtype)
        return prev + self.cfg.context_noise * std * noise

    def loss(
        self,
        prev: Tensor,
        prev_mask: Tensor,
        w: Tensor,
        text: TextFeatures,
        uncond_text: TextFeatures,
        generator: torch.Generator | None = None,
        person_text: TextFeatures | None = None,
        person_present: Tensor | None = None,
        endpoint: bool = False,
    ) -> dict[str, Tensor]:
        """Semi-noise loss for reactions ``w`` (B, p, r) to real previous latents.

        ``person_text`` / ``person_present``: the reacting person's own prompt where it has
        one (a model with ``denoiser.person_text``; dropped at ``p_person_drop``).
        ``endpoint``: also return the reaction the prediction points at (``endpoint``,
        (B, p, r) latents, with gradient; :func:`umf.flows.reaction_endpoint`) and the
        times ``t`` (B,): for a loss on the decoded reaction (``train_sflow.foot_loss``).

        ``prev`` (B, n_prev, p, r) with ``prev_mask`` (B, n_prev) (True = that person
        exists). ``total`` = reaction + lambda_recon * recon (backpropagate it); the two
        parts are returned detached for logging. Context noise applies in training mode
        only. Gradients reach the context adapter through both the state and the targets.
        """
        prev, w = self.latent_norm.normalize(prev), self.latent_norm.normalize(w)
        if self.training:
            prev = self.perturb_context(prev, prev_mask, generator)
        context = self.context(prev, prev_mask)
        sample = semi_noise_training_sample(
            context, w, reaction_only=self.cfg.reaction_only, generator=generator,
            reaction_noise=self.cfg.reaction_noise,
        )  # fmt: skip
        b = w.shape[0]
        drop = torch.rand(b, generator=generator, device=w.device) < self.cfg.p_uncond
        cond = training_text(self.net, self.cfg.p_person_drop, text, uncond_text, drop,
                             person_text, person_present, generator,
                             self.cfg.p_scene_drop)  # fmt: skip
        pred = self.velocity(sample.x, sample.t, cond, context)
        parts = semi_noise_loss(
            pred,
            sample.target,
            lambda_recon=self.cfg.lambda_recon,
            reaction_only=self.cfg.reaction_only,
        )
        out = {
            "total": parts.total,
            "reaction": parts.reaction.detach(),
            "recon": parts.recon.detach(),
        }
        if endpoint:
            # the state detached: a loss on the endpoint shapes the velocity, not the context
            end = reaction_endpoint(sample.x.detach(), pred, sample.t,
                                    reaction_only=self.cfg.reaction_only)  # fmt: skip
            out["endpoint"] = self.latent_norm.denormalize(end)
            out["t"] = sample.t.detach()
        return out

    @torch.no_grad()
    def sample(
        self,
        prev: Tensor,
        prev_mask: Tensor,
        text: TextFeatures,
        uncond_text: TextFeatures | None = None,
        *,
        steps: int | None = None,
        solver: Method | None = None,
        guidance: GuidanceArg = FROM_CONFIG,
        generator: Generators = None,
        person_text: TextFeatures | None = None,
        person_present: Tensor | None = None,
        warm: Tensor | None = None,
        warm_t: float | None = None,
    ) -> tuple[Tensor, int]:
        """The next person's latent (B, p, r) and the NFE, integrating the ODE once.

        ``warm`` (B, p, r) on the VAE's scale: a proposed reaction to start from at
        ``warm_t`` (None: ``warm_start``; :func:`umf.flows.warm_state`; ignored when 0).

        Defaults come from the config; ``guidance`` None or 1.0 disables CFG (the
        unconditional side has neither prompt). ``person_text`` / ``person_present``: the
        new person's own prompt, guided by ``person_guidance`` (None: the scene's scale)
        apart from the scene prompt (:func:`umf.flows.composed_guidance`). NFE counts
        guided-field evaluations (``steps * evals per solver step``). Runs in eval mode.
        """
        b = text.tokens.shape[0]
        scale = resolve_guidance(guidance, self.cfg.guidance)
        with evaluating(self):
            context = self.context(self.latent_norm.normalize(prev), prev_mask)
            scene_token = self.net.encode_text(text)
            cond: dict[str, Any] = {"text": scene_token}
            if person_text is not None:
                cond["text"] = scene_token + self.net.person_token(person_text, b, person_present)
            field: Callable[..., Tensor] = self.velocity
            if scale is not None:
                if uncond_text is None:
                    raise ValueError("classifier-free guidance needs uncond_text")
                uncond = {"text": encode_uncond(self.net, uncond_text, b)}
                if person_text is None:
                    field = classifier_free_guidance(self.velocity, scale, cond, uncond)
                else:  # the own prompt guided apart from the scene's
                    own = scale if self.cfg.person_guidance is None else self.cfg.person_guidance
                    field = composed_guidance(self.velocity, scale, own, cond,
                                              {"text": scene_token}, uncond)  # fmt: skip
                cond = {}
            w, nfe = sample_semi_noise(
                field,
                context,
                steps=self.cfg.steps if steps is None else steps,
                method=solver or self.cfg.solver,  # type: ignore[arg-type]
                reaction_only=self.cfg.reaction_only,
                generator=generator,
                cond={**cond, "context": context},  # beside the state (context_condition)
                reaction_noise=self.cfg.reaction_noise,
                warm=None if warm is None else self.latent_norm.normalize(warm),
                warm_t=self.cfg.warm_start if warm_t is None else warm_t,
            )
        return self.latent_norm.denormalize(w), nfe
