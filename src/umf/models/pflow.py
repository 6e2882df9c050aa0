"""P-Flow: the first person's latent from text (paper Sec. 4.2.1, SPEC 6).

A thin module: the pyramid maths (training sample, jump, sampler) lives in
``umf.flows.pyramid``; this binds it to a ``FlowTransformer`` and adds classifier-free
guidance and the single-/multi-person corpus weighting.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from umf.config import PFlowConfig
from umf.flows import (
    Method,
    PyramidConfig,
    classifier_free_guidance,
    composed_guidance,
    default_steps,
    flow_matching_loss,
    initial_noise,
    pyramid_training_sample,
    sample_finest_from,
    sample_pyramid,
)
from umf.flows.noise import Generators
from umf.models.denoiser import (
    FROM_CONFIG,
    FlowTransformer,
    GuidanceArg,
    evaluating,
    expand_text,
    repeat_text,
    resolve_guidance,
    training_text,
)
from umf.models.latent_normalizer import LatentNormalizer
from umf.text import Pooling, TextFeatures


def resolve_steps(steps: int | Sequence[int], num_stages: int) -> tuple[int, ...]:
    """Per-stage step counts, coarse -> fine.

    K counts are used as given; a single count is split over the stages like the paper's
    45/5; K = 1 (the no-pyramid ablation) keeps the total of a per-stage budget, so
    ``--set pflow.num_stages=1`` compares at the same number of steps.
    """
    seq = (steps,) if isinstance(steps, int) else tuple(int(s) for s in steps)
    if len(seq) == num_stages:
        return seq
    if num_stages == 1:
        return (sum(seq),)
    if len(seq) == 1:
        return default_steps(num_stages, seq[0])
    raise ValueError(f"need {num_stages} step counts (coarse -> fine), got {seq}")


def encode_uncond(net: FlowTransformer, uncond_text: TextFeatures, batch: int) -> Tensor:
    """Text token of the empty prompt for ``batch`` rows (computed on one row if given one)."""
    u = net.encode_text(uncond_text)
    if u.shape[0] == batch:
        return u
    if u.shape[0] != 1:
        raise ValueError(f"uncond_text has {u.shape[0]} rows; expected 1 or {batch}")
    return u.expand(batch, -1)


def stage_scales(cfg: PFlowConfig, guidance: GuidanceArg = FROM_CONFIG) -> tuple[float | None, ...]:
    """CFG scale of each pyramid stage, coarse -> fine (None: the plain conditional model).

    From the config, every stage takes ``guidance`` except the finest, which takes
    ``fine_guidance`` when set (with one stage, that stage is the finest); a ``guidance``
    given by the caller applies to every stage. Scale 1 is the plain conditional model
    (no guidance), scale 0 the unconditional one.
    """
    scale = resolve_guidance(guidance, cfg.guidance)
    fine = scale
    if guidance is FROM_CONFIG and cfg.fine_guidance is not None:
        if cfg.fine_guidance < 0:
            raise ValueError(f"pflow.fine_guidance must be >= 0, got {cfg.fine_guidance}")
        fine = resolve_guidance(cfg.fine_guidance, cfg.guidance)
    return (scale,) * (cfg.num_stages - 1) + (fine,)


def _stage_field(
    net: nn.Module,
    scales: Sequence[float | None],
    cond: dict[str, Any],
    uncond: dict[str, Any],
    scene: dict[str, Any] | None = None,
    own_scale: float | None = None,
    own_alone: dict[str, Any] | None = None,
) -> Callable[..., Tensor]:
    """The velocity field the pyramid sampler integrates, guided per stage by ``scales``
    (coarse -> fine; stage K is the coarsest, stage 1 the finest). ``scene``: the scene
    prompt alone, when ``cond`` adds an own prompt: then each guided stage guides the own
    prompt by ``own_scale`` (None: the stage's scale) apart from the scene's
    (:func:`umf.flows.composed_guidance`); with ``own_alone`` (the own prompt as a prompt
    alone) conjoined with it. An unguided stage reads ``cond``, both prompts together."""

    def plain(x: Tensor, t: Tensor, **shared: Any) -> Tensor:
        return net(x, t, **shared, **cond)

    def guided(s: float) -> Callable[..., Tensor]:
        if scene is None:
            return classifier_free_guidance(net, s, cond, uncond)
        both = cond if own_alone is None else own_alone
        return composed_guidance(net, s, s if own_scale is None else own_scale, both, scene,
                                 uncond, own_alone is not None)  # fmt: skip

    fields: dict[float | None, Callable[..., Tensor]] = {
        s: plain if s is None else guided(s) for s in set(scales)
    }
    k = len(scales)
    if len(fields) == 1:
        return fields[scales[0]]

    def field(x: Tensor, t: Tensor, *, stage: Tensor, **shared: Any) -> Tensor:
        return fields[scales[k - int(stage[0])]](x, t, stage=stage, **shared)

    return field


def _own_alone(own: Tensor, empty: Tensor, present: Tensor | None) -> Tensor:
    """The own prompt's text token per row, the empty prompt's where a row has none: its
    conjoined term v_own - v_u is then zero, and the row is guided by the scene alone."""
    if present is None:
        return own
    keep = present.to(own.device, torch.bool).reshape(-1, *[1] * (own.dim() - 1))
    return torch.where(keep, own, empty.expand_as(own))


class PFlow(nn.Module):
    """Pyramidal flow matching over (B, p, r) latents conditioned on text and dataset.

    ``forward`` is ``loss`` so that a DistributedDataParallel wrapper sees the training
    computation. Dataset 0 is the single-person corpus, 1 the multi-person one.
    """

    def __init__(
        self,
        cfg: PFlowConfig,
        num_tokens: int,
        latent_dim: int,
        text_dim: int,
        *,
        text_pool: Pooling = "mean",
    ):
        super().__init__()
        self.cfg = cfg
        self.num_tokens, self.latent_dim = num_tokens, latent_dim
        self.pyramid = PyramidConfig(
            layout=cfg.layout,
            num_stages=cfg.num_stages,
            num_tokens=num_tokens,
            g=cfg.g,
            starts=cfg.starts,
        )
        # fit by the stage
        detail = cfg.layout if cfg.detail_norm else None
        self.latent_norm = LatentNormalizer(num_tokens, latent_dim, detail_layout=detail)
        self.net = FlowTransformer(
            cfg.denoiser,
            latent_dim,
            latent_dim,
            text_dim,
            num_tokens,
            num_stages=cfg.num_stages,
            num_datasets=cfg.num_datasets,
            text_pool=text_pool,
            layout=cfg.layout,
        )

    def forward(self, *args: Any, **kwargs: Any) -> dict[str, Tensor]:
        return self.loss(*args, **kwargs)

    def loss(
        self,
        z1: Tensor,
        text: TextFeatures,
        uncond_text: TextFeatures,
        dataset: Tensor | None = None,
        generator: torch.Generator | None = None,
        person_text: TextFeatures | None = None,
        person_present: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """Masked pyramid flow-matching loss of a batch; each sample draws its own stage.

        ``person_text`` / ``person_present``: person 1's own prompt where it has one
        (a model with ``denoiser.person_text``; dropped at ``p_person_drop``).

        ``total`` (to backpropagate) = mean over samples of weight * MSE, weight
        ``single_person_weight`` for dataset 0, else 1; ``mse`` (unweighted) and
        ``stage{k}`` (stages present in the batch) are detached, for logging.
        """
        b = z1.shape[0]
        if dataset is None and self.net.num_datasets > 0:
            raise ValueError("P-Flow with dataset tokens needs dataset=(B,) long")
        z1 = self.latent_norm.normalize(z1)
        sample = pyramid_training_sample(z1, self.pyramid, generator=generator)
        drop = torch.rand(b, generator=generator, device=z1.device) < self.cfg.p_uncond
        cond = training_text(self.net, self.cfg.p_person_drop, text, uncond_text, drop,
                             person_text, person_present, generator,
                             self.cfg.p_scene_drop)  # fmt: skip
        pred = self.net(
            sample.x,
            sample.t,
            cond,
            stage=sample.stage,
            dataset=dataset,
            token_mask=sample.mask,
        )
        single = torch.zeros(b, dtype=torch.bool, device=z1.device)
        if dataset is not None:
            single = dataset.to(z1.device) == 0
        total = pred.new_zeros(())
        for sel, weight in ((single, self.cfg.single_person_weight), (~single, 1.0)):
            idx = sel.nonzero().squeeze(1)
            if idx.numel():
                group = flow_matching_loss(pred[idx], sample.target[idx], sample.mask[idx])
                total = total + weight * idx.numel() / b * group
        out = {
            "total": total,
            "mse": flow_matching_loss(pred, sample.target, sample.mask).detach(),
        }
        for w in self.pyramid.windows:
            idx = (sample.stage == w.stage).nonzero().squeeze(1)
            if idx.numel():
                out[f"stage{w.stage}"] = flow_matching_loss(
                    pred[idx], sample.target[idx], sample.mask[idx]
                ).detach()
        return out

    @torch.no_grad()
    def sample(
        self,
        text: TextFeatures,
        uncond_text: TextFeatures | None = None,
        *,
        num_samples: int = 1,
        dataset: int | Tensor = 1,
        steps: int | Sequence[int] | None = None,
        solver: Method | None = None,
        guidance: GuidanceArg = FROM_CONFIG,
        generator: Generators = None,
        person_text: TextFeatures | None = None,
        person_present: Tensor | None = None,
        warm: Tensor | None = None,
        warm_t: float = 0.0,
    ) -> tuple[Tensor, int]:
        """Generate ``num_samples`` latents per prompt: (B * num_samples, p, r) on the VAE's
        scale, and the NFE.

        ``warm`` (B * num_samples, p, r) on the VAE's scale and ``warm_t`` in (0, 1): sample
        again from a proposal instead, entering the finest stage at local time ``warm_t`` on
        the path towards it (:func:`umf.flows.pyramid.sample_finest_from`).

        ``person_text`` (B rows) / ``person_present`` (B,): person 1's own prompt (a model
        with per-person prompts); a guided stage then guides the scene prompt by its scale
        and the own prompt by ``person_guidance`` (None: the same), one forward over three
        batches (:func:`umf.flows.composed_guidance`); the unconditional side has neither.
        With ``person_composition`` "and" the own prompt is conjoined as a prompt alone
        (its token through the scene's text head) rather than added to the scene's.

        Defaults come from the config (per stage: :func:`stage_scales`); ``guidance`` None
        or 1.0 disables CFG, and ``uncond_text`` is needed only when some stage is guided.
        The NFE counts field evaluations, ``sum(steps) * evals per solver step``: one
        double-batch forward each in a guided stage, one plain forward in an unguided one.
        Runs in eval mode and restores the previous mode.
        """
        if person_text is not None:  # one row per prompt (or one for all), then per sample
            rows = text.tokens.shape[0]
            person_text = repeat_text(expand_text(person_text, rows), num_samples)
            if person_present is not None:
                person_present = person_present.reshape(-1).expand(rows)
                person_present = person_present.repeat_interleave(num_samples)
        text = repeat_text(text, num_samples)
        param = next(self.parameters())
        b = text.tokens.shape[0]
        with evaluating(self):
            scene_token = self.net.encode_text(text)
            cond: dict[str, Any] = {"text": scene_token}
            if person_text is not None:
                cond["text"] = scene_token + self.net.person_token(person_text, b, person_present)
            scales = stage_scales(self.cfg, guidance)
            if self.net.num_datasets > 0:
                ds = torch.as_tensor(dataset, dtype=torch.long, device=param.device)
                ds = ds.expand(b) if ds.dim() == 0 else ds.repeat_interleave(num_samples)
                cond["dataset"] = ds
            uncond: dict[str, Any] = {}
            if any(s is not None for s in scales):
                if uncond_text is None:
                    raise ValueError("classifier-free guidance needs uncond_text")
                if uncond_text.tokens.shape[0] not in (1, b):
                    uncond_text = repeat_text(uncond_text, num_samples)
                uncond = {**cond, "text": encode_uncond(self.net, uncond_text, b)}
            scene = own_alone = None  # an own prompt is guided apart from the scene's
            if person_text is not None and uncond:
                scene = {**cond, "text": scene_token}
                if self.cfg.person_composition == "and":  # through the scene's text head
                    alone = self.net.encode_text(person_text)
                    own_alone = {**cond, "text": _own_alone(alone, uncond["text"], person_present)}
            field = _stage_field(self.net, scales, cond, uncond, scene, self.cfg.person_guidance,
                                 own_alone)  # fmt: skip
            k = self.pyramid.num_stages
            per_stage = resolve_steps(self.cfg.steps if steps is None else steps, k)
            if warm is not None:
                z, nfe = sample_finest_from(field, self.latent_norm.normalize(warm),
                                            self.pyramid, warm_t, steps=per_stage[-1],
                                            method=solver or self.cfg.solver,  # type: ignore[arg-type]
                                            generator=generator)  # fmt: skip
                return self.latent_norm.denormalize(z), nfe
            noise = initial_noise(
                self.pyramid,
                b,
                self.latent_dim,
                generator=generator,
                device=param.device,
                dtype=param.dtype,
            )
            z, nfe = sample_pyramid(
                field,
                noise,
                self.pyramid,
                steps=per_stage,
                method=solver or self.cfg.solver,  # type: ignore[arg-type]
                generator=generator,
            )
        return self.latent_norm.denormalize(z), nfe
