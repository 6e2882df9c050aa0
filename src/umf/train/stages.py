"""The three training stages of UMF as :class:`umf.train.loop.Stage` objects.

- ``VAEStage``: the motion VAE on single-person crops (randomly placed) and on scenes
  (every person, with the interaction term).
- ``PFlowStage``: P-Flow on the frozen VAE's latents of person 1, alternating batches of
  the single-person corpus (dataset 0) and of the scenes (dataset 1).
- ``SFlowStage``: S-Flow on scenes: person i's latent as a reaction to the latents of the
  *real* people before it (SPEC 7, defect a), VAE and P-Flow frozen.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from umf.config import UMFConfig
from umf.models.pflow import PFlow
from umf.models.sflow import SFlow
from umf.models.vae import MotionVAE, vae_losses
from umf.representation import POS, Normalizer
from umf.text import TextFeatureCache, TextFeatures
from umf.train.foot_slide import FOOT_FRAMES, decoded_foot_slide
from umf.train.placement import decoded_place_errors


def _is_scene(batch: dict[str, Any]) -> bool:
    return batch["features"].dim() == 4


def flatten_scenes(batch: dict[str, Any]) -> tuple[Tensor, Tensor, Tensor]:
    """(B, P, T, 262) scenes -> rows (R, T, 262) of present people, mask (R, T), people (B, P).

    ``people[s, k]`` is the row of person k of scene s, or -1 when the slot is empty.
    """
    feats, mask, present = batch["features"], batch["mask"], batch["people_mask"]
    b, p = present.shape
    rows = feats[present]
    row_mask = mask[:, None, :].expand(b, p, -1)[present]
    people = torch.full((b, p), -1, dtype=torch.long, device=feats.device)
    people[present] = torch.arange(int(present.sum()), device=feats.device)
    return rows, row_mask, people


class DeviceGenerator:
    """A seeded generator created on the device of the data it draws for (a CPU generator
    cannot fill a CUDA tensor); moving to another device restarts from the seed."""

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self._gen: torch.Generator | None = None

    def on(self, device: torch.device | str) -> torch.Generator | None:
        from umf.streams import device_generator

        device = torch.device(device)
        if self._gen is None or self._gen.device != device:
            if device.type == "meta":
                return None
            self._gen = device_generator(self.seed, device)
        return self._gen


def mpjpe(
    x_hat: Tensor, x: Tensor, mask: Tensor, normalizer: Normalizer, root_relative: bool = False
) -> Tensor:
    """Mean per-joint position error (m) over valid frames; ``root_relative``: of the pose
    (both skeletons' pelvises moved to the origin), which the root error cannot hide."""
    pred = normalizer.denormalize(x_hat)[..., POS].reshape(*x.shape[:2], 22, 3)
    true = normalizer.denormalize(x)[..., POS].reshape(*x.shape[:2], 22, 3)
    if root_relative:
        pred, true = pred - pred[..., :1, :], true - true[..., :1, :]
    err = (pred - true).norm(dim=-1).mean(-1)
    return (err * mask).sum() / mask.sum().clamp_min(1)


class VAEStage:
    name = "vae"

    def __init__(
        self,
        config: UMFConfig,
        normalizer: Normalizer,
        vae: MotionVAE | None = None,
        body_normalizer: Normalizer | None = None,
    ):
        self.config = config
        self.normalizer = normalizer
        self.vae = vae or MotionVAE(config.vae)
        self.vae.set_normalizers(normalizer, body_normalizer)
        if config.train_vae.decoder_only:
            self.vae.freeze_encoder()

    def modules(self) -> dict[str, nn.Module]:
        return {"vae": self.vae}

    def trainable(self) -> nn.Module:
        return self.vae

    def _losses(self, batch: dict[str, Any]) -> tuple[dict[str, Tensor], Tensor, Tensor, Tensor]:
        people = None
        if _is_scene(batch):
            x, mask, people = flatten_scenes(batch)
        else:
            x, mask = batch["features"], batch["mask"]
        out = self.vae(x, mask)
        losses = vae_losses(
            out, x, mask, self.normalizer, self.config.vae, people=people, fps=self.config.fps
        )
        return losses, out.x_hat, x, mask

    def training_step(self, batch: dict[str, Any], step: int) -> dict[str, Tensor]:
        return self._losses(batch)[0]

    @torch.no_grad()
    def validation_step(self, batch: dict[str, Any]) -> dict[str, float]:
        losses, x_hat, x, mask = self._losses(batch)
        out = {k: float(v) for k, v in losses.items()}
        out["mpjpe_m"] = float(mpjpe(x_hat, x, mask, self.normalizer))
        out["mpjpe_pose_m"] = float(mpjpe(x_hat, x, mask, self.normalizer, root_relative=True))
        return out


class _LatentStage:
    """Shared by the flow stages: frozen VAE encoder and cached frozen text features."""

    def __init__(self, config: UMFConfig, vae: MotionVAE, text: TextFeatureCache):
        self.config = config
        self.vae = vae.eval().requires_grad_(False)
        self.text = text

    @torch.no_grad()
    def latents(self, x: Tensor, mask: Tensor) -> Tensor:
        """Deterministic latents (the posterior means) of normalised features."""
        self.vae.eval()
        mu, _ = self.vae.encode(x, mask)
        return mu

    def encode_text(self, captions: list[str], device) -> tuple[TextFeatures, TextFeatures]:
        text = self.text.encode(captions).to(device)
        uncond = self.text.encode([""] * len(captions)).to(device)
        return text, uncond

    def person_text(
        self, net: nn.Module, own: list[str], device
    ) -> dict[str, TextFeatures | Tensor]:
        """The flow's per-person keywords for these own captions ("" = none), or nothing
        when the model has no per-person prompts."""
        if getattr(net, "person_proj", None) is None:
            return {}
        present = torch.tensor([bool(c) for c in own], dtype=torch.bool, device=device)
        return {"person_text": self.text.encode(own).to(device), "person_present": present}


def own_captions(batch: dict[str, Any], person: list[int] | Tensor) -> list[str]:
    """Each row's own caption of person ``person[i]`` ("" where the item has none)."""
    owns = batch.get("person_captions") or [[]] * len(person)
    if not any(c for own in owns for c in own):  # none at all: the indices are not read
        return [""] * len(person)
    ks = person.tolist() if isinstance(person, Tensor) else list(person)
    return [own[k] if k < len(own) else "" for own, k in zip(owns, ks, strict=True)]


class PFlowStage(_LatentStage):
    name = "pflow"

    def __init__(self, config, vae, text, pflow: PFlow | None = None, seed: int = 0):
        super().__init__(config, vae, text)
        p, r = vae.latent_shape
        self.pflow = pflow or PFlow(config.pflow, p, r, text.encoder.dim)
        self.generator = DeviceGenerator(seed)

    def modules(self) -> dict[str, nn.Module]:
        return {"pflow": self.pflow, "vae": self.vae}

    def trainable(self) -> nn.Module:
        return self.pflow

    def _inputs(self, batch):
        own = own_captions(batch, [0] * len(batch["captions"]))  # person 1's
        if "z" in batch:  # from a latent bank
            z1 = batch["z"][:, 0]
            return z1, batch["dataset"].long().to(z1.device), batch["captions"], own
        if _is_scene(batch):  # person 1 of each scene, multi-person corpus
            x, mask = batch["features"][:, 0], batch["mask"]
            dataset = torch.ones(x.shape[0], dtype=torch.long)
        else:
            x, mask = batch["features"], batch["mask"]
            dataset = batch["dataset"].long()
        return self.latents(x, mask), dataset.to(x.device), batch["captions"], own

    def training_step(self, batch: dict[str, Any], step: int) -> dict[str, Tensor]:
        z1, dataset, captions, own = self._inputs(batch)
        text, uncond = self.encode_text(captions, z1.device)
        gen = self.generator.on(z1.device)
        person = self.person_text(self.pflow.net, own, z1.device)
        return self.pflow(z1, text, uncond, dataset=dataset, generator=gen, **person)

    @torch.no_grad()
    def validation_step(self, batch: dict[str, Any]) -> dict[str, float]:
        z1, dataset, captions, own = self._inputs(batch)
        text, uncond = self.encode_text(captions, z1.device)
        gen = DeviceGenerator(1234).on(z1.device)  # same noise every validation
        person = self.person_text(self.pflow.net, own, z1.device)
        losses = self.pflow.loss(z1, text, uncond, dataset, gen, **person)
        return {k: float(v) for k, v in losses.items()}


class SFlowStage(_LatentStage):
    name = "sflow"

    def __init__(self, config, vae, text, sflow: SFlow | None = None, backbone=None, seed: int = 0,
                 normalizer: Normalizer | None = None):  # fmt: skip
        super().__init__(config, vae, text)
        p, r = vae.latent_shape
        self.sflow = sflow or SFlow(config.sflow, p, r, text.encoder.dim, backbone=backbone)
        self.generator = DeviceGenerator(seed)
        self.normalizer = normalizer  # the corpus's: the foot loss decodes to metres
        for name in ("foot_loss", "place_loss", "joint_loss"):
            if getattr(config.train_sflow, name) > 0 and normalizer is None:
                raise ValueError(f"train_sflow.{name} needs the corpus normaliser")
        # the feet are read over the shortest training crop (every latent describes at least
        # that many frames), at most FOOT_FRAMES (the decoder's cost)
        self.foot_frames = max(2, min(FOOT_FRAMES, config.train_sflow.min_frames,
                                      config.vae.max_frames))  # fmt: skip

    def modules(self) -> dict[str, nn.Module]:
        return {"sflow": self.sflow, "vae": self.vae}

    def trainable(self) -> nn.Module:
        return self.sflow

    def _inputs(self, batch):
        if "z" in batch:  # from a latent bank
            lat, present = batch["z"], batch["people_mask"]
        else:
            rows, mask, people = flatten_scenes(batch)
            z = self.latents(rows, mask)  # (R, p, r)
            present = people >= 0
            lat = z.new_zeros(*people.shape, *z.shape[1:])
            lat[present] = z[people[present]]
        b, p_max = present.shape
        # one reacting person per scene: a random index among persons 2..P of that scene
        counts = present.sum(1)
        device = present.device
        u = torch.rand(b, generator=self.generator.on(device), device=device)
        k = 1 + (u * (counts - 1).clamp_min(1)).long()
        k = torch.minimum(k, counts - 1).clamp_min(1)
        prev_mask = torch.arange(p_max, device=device)[None, :] < k[:, None]
        w = lat[torch.arange(b, device=device), k]
        return lat, prev_mask, w, batch["captions"], own_captions(batch, k)

    def training_step(self, batch: dict[str, Any], step: int) -> dict[str, Tensor]:
        prev, prev_mask, w, captions, own = self._inputs(batch)
        text, uncond = self.encode_text(captions, w.device)
        gen = self.generator.on(w.device)
        person = self.person_text(self.sflow.net, own, w.device)
        out = self.sflow(prev, prev_mask, w, text, uncond, generator=gen,
                         endpoint=self._decodes, **person)  # fmt: skip
        return self._with_feet(out, w)

    @property
    def _decodes(self) -> bool:
        """Whether a loss on the decoded reaction is on (feet, placement or joints)."""
        t_cfg = self.config.train_sflow
        return t_cfg.foot_loss > 0 or t_cfg.place_loss > 0 or t_cfg.joint_loss > 0

    def _with_feet(self, out: dict[str, Tensor], w: Tensor) -> dict[str, Tensor]:
        """``total`` plus the weighted losses on the decoded reaction where they are on: the
        feet (logged as ``foot``), the placement (``place``) and the joints (``joint``)."""
        if "endpoint" not in out:
            return out
        t_cfg = self.config.train_sflow
        w_hat, t = out.pop("endpoint"), out.pop("t")
        fusion = self.config.vae.fusion_weights(reaction=True)  # as the pipeline decodes them
        kw = {"frames": self.foot_frames, "fusion": fusion}
        losses: dict[str, Tensor] = {}
        if t_cfg.foot_loss > 0:
            losses["foot"] = decoded_foot_slide(self.vae, self.normalizer, w, w_hat, t,
                                                t_cfg.foot_loss_min_t, **kw)  # fmt: skip
        if t_cfg.place_loss > 0 or t_cfg.joint_loss > 0:  # one decoding for both
            early = decoded_place_errors(self.vae, self.normalizer, w, w_hat, t,
                                         t_cfg.place_loss_max_t, **kw)  # fmt: skip
            losses.update({k: v for k, v in early.items() if getattr(t_cfg, f"{k}_loss") > 0})
        for name, value in losses.items():
            out["total"] = out["total"] + getattr(t_cfg, f"{name}_loss") * value
            out[name] = value.detach()
        return out

    @torch.no_grad()
    def validation_step(self, batch: dict[str, Any]) -> dict[str, float]:
        prev, prev_mask, w, captions, own = self._inputs(batch)
        text, uncond = self.encode_text(captions, w.device)
        gen = DeviceGenerator(1234).on(w.device)
        person = self.person_text(self.sflow.net, own, w.device)
        losses = self.sflow.loss(prev, prev_mask, w, text, uncond, generator=gen,
                                 endpoint=self._decodes, **person)  # fmt: skip
        return {k: float(v) for k, v in self._with_feet(losses, w).items()}
