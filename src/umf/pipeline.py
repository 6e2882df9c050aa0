"""Algorithm 1 of the paper: text + N -> N synchronized motions.

1. P-Flow generates person 1's latent from the text (pyramidal flow matching).
2. For i = 2..N the context adapter pools the latents of everybody generated so far and
   S-Flow integrates from that context to person i's latent (one ODE pass).
3. The VAE decodes every latent into 262-d features, hence joints.
4. Each person becomes one rigid body (:mod:`umf.kinematics`): fitted bone lengths, local
   rotations refined towards the decoded joints, planted feet pinned, nobody in the floor.

:class:`UMFPipeline` holds the frozen text encoder, the VAE, P-Flow, S-Flow and the
normaliser, and returns :class:`umf.scene.Scene` objects. ``UMFPipeline.from_pretrained(dir)``
loads a model directory written by ``umf train`` or :meth:`UMFPipeline.save_pretrained`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from umf.clean_up import clean_up as clean_up  # re-exported: the clean-up's home is umf.clean_up
from umf.clean_up import clean_up_scenes
from umf.clean_up import delivered_joints as delivered_joints
from umf.clean_up import place_people as place_people
from umf.config import MULTI_PERSON, SINGLE_PERSON, UMFConfig
from umf.errors import UMFError
from umf.model_checks import (
    MAX_MODEL_BYTES,
    check_config_values,
    check_model_weights,
    check_weight_shapes,
)
from umf.models.denoiser import FROM_CONFIG
from umf.person_prompts import (
    check_person_prompts,
    person_meta,
    person_text,
    takes_person_prompts,
)
from umf.reaction_bank import ReactionBank
from umf.representation import (
    CONTACT,
    Normalizer,
    RigidTransform,
    assemble_features,
    canonical_transform,
    features_to_joints,
    fuse_positions,
    joints_to_rot6d,
    leader_frame,
    pin_floor_start,
    transform_features,
)
from umf.reroll import reroll_person
from umf.scene import Scene
from umf.separation import touching_distances as touching_distances  # re-exported
from umf.streams import fresh_seed, scene_generators
from umf.take_start import start_couples, start_partners
from umf.text import respell_prompt
from umf.validation import (
    MAX_PEOPLE,
    Request,
    check_actor,
    check_finite,
    check_for_model,
    check_request,
    chunk_size,
    chunks,
)
from umf.warm_start import mirror_text, sample_added

__all__ = ["MAX_PEOPLE", "Scene", "UMFPipeline", "default_model_dir"]  # Scene: umf.scene


class UMFPipeline:
    """The whole model for sampling: text encoder, VAE, P-Flow, S-Flow, normaliser."""

    def __init__(
        self,
        config: UMFConfig,
        text_encoder,
        vae,
        pflow,
        sflow,
        normalizer: Normalizer,
        name: str = "",
    ) -> None:
        self.config = config
        self.text_encoder = text_encoder
        self.vae = vae.eval()
        self.pflow = pflow.eval()
        self.sflow = sflow.eval()
        self.normalizer = normalizer
        self.name = name
        self.device = torch.device("cpu")
        self.vocabulary = None  # what the model was trained on (umf.coverage), when it says
        self.reactions = None  # its real reactions (umf.reaction_bank), when it has them

    # ------------------------------------------------------------------ loading
    @classmethod
    def build(cls, config: UMFConfig, normalizer: Normalizer | None = None, text_encoder=None):
        """Fresh (untrained) modules for ``config``; used by training and tests."""
        from umf.models.pflow import PFlow
        from umf.models.sflow import SFlow
        from umf.models.vae import MotionVAE
        from umf.text import build_text_encoder

        enc = text_encoder or build_text_encoder(
            config.text.encoder, config.text.path, max_length=config.text.max_length
        )
        vae = MotionVAE(config.vae)
        p, r = vae.latent_shape
        pflow = PFlow(config.pflow, p, r, enc.dim)
        backbone = pflow.net if config.sflow.shared_backbone else None
        sflow = SFlow(config.sflow, p, r, enc.dim, backbone=backbone)
        if normalizer is None:
            normalizer = Normalizer(torch.zeros(262), torch.ones(262))
        return cls(config, enc, vae, pflow, sflow, normalizer)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, text_encoder=None) -> UMFPipeline:
        """Load a model directory (default: the bundled model shipped with umf).

        A model directory is a umf checkpoint with the modules ``vae``, ``pflow`` and
        ``sflow`` (``umf train export`` writes one); every problem is a one-line UMFError.
        ``config.json`` is checked (types, ranges, a dry-run build on the meta device, shapes
        against the weight files' headers) before anything is allocated, and the loaded
        weights and normaliser must be finite.
        """
        from umf.checkpoint import load_checkpoint, read_info
        from umf.text import build_text_encoder

        path = Path(path) if path is not None else default_model_dir()
        if not path.is_dir():
            raise UMFError(f"model not found: {path}")
        info = read_info(path)
        missing = {"vae", "pflow", "sflow"} - set(info.get("modules", []))
        if missing:
            raise UMFError(f"{path}: not a complete umf model (no {', '.join(sorted(missing))})")
        try:
            config = UMFConfig.from_dict(json.loads((path / "config.json").read_text()))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise UMFError(f"{path}/config.json: unreadable ({exc})") from exc
        except UMFError as exc:
            raise UMFError(f"{path}/config.json: {exc}") from exc
        try:
            check_config_values(config)
        except UMFError as exc:
            raise UMFError(f"{path}/config.json: {exc}") from exc
        enc = text_encoder or build_text_encoder(
            config.text.encoder, config.text.path, max_length=config.text.max_length
        )
        check_weight_shapes(path, dry_run_build(config, enc.dim))
        pipe = cls.build(config, None, enc)
        modules = {"vae": pipe.vae, "pflow": pipe.pflow, "sflow": pipe.sflow}
        ck = load_checkpoint(path, modules)
        if ck.normalizer is None:
            raise UMFError(f"{path}: missing normalizer.safetensors")
        check_model_weights(modules, ck.normalizer, path)
        pipe.normalizer = ck.normalizer
        pipe.name = str(info.get("name") or path.name)
        from umf.coverage import Vocabulary

        pipe.vocabulary = Vocabulary.load(path)
        pipe.reactions = ReactionBank.load(path, pipe.vae.latent_shape)
        for m in (pipe.vae, pipe.pflow, pipe.sflow):
            m.float().eval()
        return pipe

    def save_pretrained(self, path: str | Path, name: str | None = None) -> Path:
        """Write this model as a directory :meth:`from_pretrained` reads (the checkpoint
        format of :mod:`umf.checkpoint`: config, VAE, P-Flow, S-Flow, normaliser), in
        float32, atomically (a failure leaves no, or the previous, directory)."""
        from umf.checkpoint import save_checkpoint

        modules = {"vae": self.vae, "pflow": self.pflow, "sflow": self.sflow}
        out = save_checkpoint(path, modules, config=self.config.to_dict(),
                              normalizer=self.normalizer, name=name or self.name)  # fmt: skip
        for extra in (self.vocabulary, self.reactions):
            if extra is not None:
                extra.save(out)
        return out

    def coverage(self, prompts: Sequence[str]) -> list[dict | None]:
        """How well each prompt is covered by what the model was trained on
        (:mod:`umf.coverage`): ``{"score", "known", "nearest"}``, or None for a model that
        carries no vocabulary."""
        if self.vocabulary is None:
            return [None] * len(prompts)
        distinct = sorted(set(prompts))
        scored = dict(zip(distinct, self.vocabulary.score(distinct, self.text_encoder),
                          strict=True))  # fmt: skip
        return [scored[p] for p in prompts]

    @property
    def person_prompts(self) -> bool:
        """Whether the model takes a prompt per person (both flows trained with them)."""
        return takes_person_prompts(self.config)

    def check_person_prompts(self, own: Sequence[str | None], acting: bool = False) -> None:
        """:func:`umf.person_prompts.check_person_prompts` for this model."""
        check_person_prompts(self.config, own, acting, f"the model {self.name}")

    def to(self, device: str | torch.device) -> UMFPipeline:
        self.device = torch.device(device)
        for m in (self.vae, self.pflow, self.sflow):
            m.to(self.device)
        if hasattr(self.text_encoder, "to"):
            self.text_encoder.to(self.device)
        return self

    # ------------------------------------------------------------------ sampling
    def _frames(self, seconds: float) -> int:
        """Feature frames of ``seconds`` of motion (checked by ``check_for_model`` first)."""
        return round(seconds * self.config.fps)

    @torch.no_grad()
    def __call__(
        self,
        prompts: str | Sequence[str],
        num_people: int = 2,
        seconds: float = 4.0,
        seed: int | None = 0,
        guidance: float | None = None,
        pflow_steps: Sequence[int] | None = None,
        sflow_steps: int | None = None,
        actor: np.ndarray | None = None,
        separate: bool = True,
        sample_indices: Sequence[int] | None = None,
        fit: bool = True,
        anchor: bool = True,
        person_prompts: Sequence[str | None] | None = None,
    ) -> list[Scene]:
        """Generate one scene per prompt (batched).

        ``person_prompts``: what each person does, beside the scene prompt, the K-th for
        person K (None, or a shorter list: that person follows the scene prompt alone), the
        same for every scene of the call; for a model trained with them
        (``denoiser.person_text``). Recorded in ``scene.meta["person_prompts"]`` with their
        coverage in ``scene.meta["person_coverage"]``.

        Scene ``i`` is a function of (model, prompt, people, seconds, seed, sample index)
        alone: its noise comes from its own generator (:mod:`umf.streams`), whatever else
        is in the call. ``sample_indices`` numbers the samples (default: 0 for the first
        copy of a prompt in ``prompts``, 1 for the second ...); ``seed`` None draws one,
        recorded in ``scene.seed``. Every argument is checked first (:mod:`umf.validation`)
        and scenes are sampled in chunks of bounded memory; non-finite output is an error.

        ``actor`` (T, 22, 3) joints in metres at the model's fps, in any frame, fixes
        person 1 (the paper's action-reaction task): it is moved into the canonical frame
        the model was trained in, the others are generated around it, and the whole scene
        is moved back, so person 1 is the user's motion exactly and everyone else stands
        in the user's own coordinates.

        ``separate`` (default) shifts people 2..N rigidly on the floor where their pelvis
        paths come closer than 0.5 m to someone generated before them, or any of their
        joints within 28 cm of another person's (:mod:`umf.separation`); the motions
        themselves are untouched and the shifts are in ``scene.meta["shifts"]``.
        Evaluation turns it off to score the raw model.

        ``fit`` (default) makes each person one rigid body (:mod:`umf.kinematics`; scene by
        scene on a CPU, every scene sampled together at once on a GPU: :func:`clean_up_scenes`):
        ``scene.joints`` is its forward kinematics, what every export writes, with
        planted feet pinned and everyone kept off the floor (the actor of a reaction is
        only fitted). ``anchor`` (default; only with ``fit``) first moves each generated
        person back along the floor by the slide of a planted foot (:mod:`umf.anchoring`):
        a body the decoder glides along with its feet planted travels only as far as its
        legs carry it; ``anchor=False`` keeps the decoded floor path (feet may skate). The
        separation is decided on the anchored paths. The decoded positions (moved by the
        separation's shifts, not anchored) stay in ``scene.raw_joints``. ``fit=False``
        (evaluation: no inverse kinematics for thousands of scenes) returns the decoded
        positions as ``joints``, neither anchored nor fitted; such a scene's files fit a
        copy when written.
        """
        req = check_request(prompts, num_people, seconds, seed, guidance, pflow_steps,
                            sflow_steps, sample_indices, person_prompts)  # fmt: skip
        frames = check_for_model(req, self.config, acting=actor is not None)
        self.check_person_prompts(req.person_prompts, acting=actor is not None)
        if actor is not None:
            actor = check_actor(actor, self.config.fps, self.config.vae.max_frames)
            frames = actor.shape[0] - 1
        seed = fresh_seed() if req.seed is None else req.seed
        covered = dict(zip(req.prompts, self.coverage(req.prompts), strict=True))
        own_meta = person_meta(self, req.person_prompts, req.num_people)
        scenes: list[Scene] = []
        for part in chunks(len(req.prompts), chunk_size(req.num_people, frames)):
            texts = [req.prompts[i] for i in part]
            indices = [req.sample_indices[i] for i in part]
            near = [(covered[t] or {}).get("contact") for t in texts]
            for scene in self._sample(texts, indices, req, seed, actor, separate, anchor, fit,
                                      near):  # fmt: skip
                if covered[scene.text] is not None:
                    scene.meta["coverage"] = covered[scene.text]
                scene.meta.update(own_meta)
                scenes.append(scene)
        return scenes

    def _sample(
        self,
        prompts: list[str],
        indices: list[int],
        req: Request,
        seed: int,
        actor: np.ndarray | None,
        separate: bool,
        anchor: bool,
        fit: bool,
        contact: list[dict | None] | None = None,
    ) -> list[Scene]:
        """One chunk of scenes, each drawing its noise from its own stream; ``contact``:
        per scene, how close the real takes its prompt is worded like let people come
        (None: the default separation)."""
        num_people, guidance = req.num_people, req.guidance
        gen = scene_generators(seed, indices, self.device)
        b = len(prompts)
        words = [respell_prompt(p, self.config.text.respell) for p in prompts]
        text = self.text_encoder.encode(words).to(self.device)
        mirror = mirror_text(self, words) if num_people > 1 else None
        uncond = self.text_encoder.encode([""] * b).to(self.device)
        nfe = 0
        frame = couples = None
        if actor is not None:
            actor_t, frame = self._canonical_actor(actor)
            t = actor_t.shape[0] - 1  # T joint frames are T - 1 feature frames
            rot6d = joints_to_rot6d(actor_t)  # local rotations: the same in the user's frame
            latents = [self._encode_actor(assemble_features(actor_t, rot6d), b)]
        else:
            t = self._frames(req.seconds)
            token = MULTI_PERSON if num_people > 1 else SINGLE_PERSON
            dataset = torch.full((b,), token, dtype=torch.long)
            pflow = dict(dataset=dataset.to(self.device),
                         steps=req.pflow_steps or self.config.pflow.steps,
                         guidance=FROM_CONFIG if guidance is None else guidance,  # per stage
                         )  # fmt: skip
            z1, n = self.pflow.sample(text, uncond, generator=gen, **pflow,
                                      **person_text(self, req.person_prompts, 0, b))  # fmt: skip
            if num_people > 1 and not any(req.person_prompts):  # worded like a real couple
                z1, couples, m = start_couples(self, z1, text, uncond, gen, contact, t, pflow)
                n += m
            latents, nfe = [z1], nfe + n
        reencode = self.config.sflow.reencode_context and num_people > 1
        placed = None  # per scene, the frame people 2..N are generated in (re-encoding)
        context = list(latents)
        if reencode and actor is None:
            lead = self.decode(z1, t)
            placed = [leader_frame(f) for f in lead]
            moved = [transform_features(f, tf) for f, tf in zip(lead, placed, strict=True)]
            context = [self._encode(torch.stack(moved))]
        sflow = {
            "steps": req.sflow_steps or self.config.sflow.steps_for(num_people),
            "guidance": self.config.sflow.guidance if guidance is None else guidance,
        }
        for k in range(1, num_people):
            prev = torch.stack(context, dim=1)
            mask = torch.ones(prev.shape[:2], dtype=torch.bool, device=self.device)
            w, n = sample_added(self, prev, mask, text, uncond, t, generator=gen,
                                own=person_text(self, req.person_prompts, k, b),
                                pflow_guidance=guidance, mirror=mirror, **sflow)  # fmt: skip
            if k == 1 and couples is not None:  # person 2 from the couple's take too
                w, m = start_partners(self, w, couples, prev, mask, text, uncond, gen, **sflow)
                n += m
            nfe += n
            latents.append(w)
            if k < num_people - 1:  # someone follows: w joins the context
                context.append(self._encode(self.decode(w, t, reaction=True)) if reencode else w)
        z = torch.stack(latents, dim=1)  # (B, N, p, r)
        check_finite(z, "the sampled latents (P-Flow / S-Flow output)")
        raw = self._decode_raw(z.flatten(0, 1), t).reshape(b, num_people, t, -1)
        # person 1 and people 2..N fuse their paths differently; an actor replaces person 1
        feats = torch.cat([self._fuse(raw[:, :1]), self._fuse(raw[:, 1:], reaction=True)], dim=1)
        if placed is not None:  # people 2..N back from person 1's re-centred frame
            back = zip(feats[:, 1:], placed, strict=True)
            feats[:, 1:] = torch.stack([transform_features(f, tf, inverse=True) for f, tf in back])
        if frame is not None:  # back into the user's frame; person 1 is their motion exactly
            feats = transform_features(feats.cpu(), frame, inverse=True)
            feats[:, 0] = assemble_features(torch.from_numpy(actor).float(), rot6d)
        check_finite(feats, "the decoded motion (VAE and normaliser)")
        feats = feats.cpu()
        # the floor: y = 0 in the canonical frame, the actor's lowest joint in theirs
        floor = 0.0 if frame is None else float(frame.origin[1])
        clean = [frame is None or k > 0 for k in range(num_people)]  # not the actor
        contacts = feats[..., CONTACT].numpy()
        decoded = features_to_joints(feats).numpy().copy()  # not a view: feats shift below
        shifts, fitted = clean_up_scenes(decoded, contacts, floor, clean, anchor, separate, fit,
                                         contact, self.device)  # fmt: skip
        if shifts.any():  # the features move with the people (positions only)
            offset = torch.from_numpy(shifts).to(feats).repeat(1, 1, 22)  # (B, N, 66)
            feats[..., :66] = feats[..., :66] + offset[:, :, None, :]
        joints = decoded + shifts[:, :, None, None, :]  # the decoded positions, separated
        check_finite(joints, "the generated joints")
        meta = {"nfe": nfe, "guidance": guidance, "num_people": num_people, "floor": floor}
        scenes = []
        took = {} if couples is None else dict(zip(couples.rows.tolist(), couples.sources,
                                                   strict=True))  # fmt: skip
        for i in range(b):
            raw, f, bodies = joints[i], feats[i].numpy(), fitted[i]
            extra = {"shifts": shifts[i].tolist(), "sample_index": indices[i]}
            if took.get(i) is not None:  # people 1 and 2 finished from this real take's crop
                extra["take"] = {**took[i], "warm_take": self.config.sflow.warm_take}
            scenes.append(Scene(raw if bodies is None else bodies.joints(), f, prompts[i],
                                self.config.fps, seed, self.name, {**meta, **extra}, raw,
                                bodies, fit=False))  # fmt: skip
        return scenes

    def reroll(
        self,
        scene: Scene,
        person: int,
        seed: int = 0,
        prompt: str | None = None,
        guidance: float | None = None,
        sflow_steps: int | None = None,
        anchor: bool = True,
        separate: bool = True,
        person_prompt: str | None = None,
    ) -> Scene:
        """A new Scene: person ``person`` (1-based, as in the files' ``-p1``, ``-p2`` ...)
        sampled again from ``seed`` as S-Flow's reaction to everybody else, whose joints,
        bodies and features are copied bit for bit (:mod:`umf.reroll`; person 1 too is
        re-rolled as a reaction to the others). ``prompt``: the scene's own by default;
        ``person_prompt``: what this person does (default: what the scene recorded)."""
        return reroll_person(self, scene, person, seed, prompt, guidance, sflow_steps, anchor,
                             separate, person_prompt)  # fmt: skip

    def decode(self, z: torch.Tensor, num_frames: int, reaction: bool = False) -> torch.Tensor:
        """Latents (B, p, r) -> de-normalised features (B, T, 262). ``reaction``: people
        2..N (the S-Flow's), whose floor path may trust its decoded positions more
        (``vae.reaction_root_fusion``): they are placed relative to person 1."""
        return self._fuse(self._decode_raw(z, num_frames), reaction)

    def _fuse(self, raw: torch.Tensor, reaction: bool = False) -> torch.Tensor:
        """Decoded features (..., T, 262) fused (``fuse_positions``) at person 1's or people
        2..N's weights; person 1 then starts over the origin with ``vae.pin_leader_start``."""
        out = fuse_positions(raw, *self.config.vae.fusion_weights(reaction))
        return pin_floor_start(out) if self.config.vae.pin_leader_start and not reaction else out

    def _decode_raw(self, z: torch.Tensor, num_frames: int) -> torch.Tensor:
        """Latents (B, p, r) -> de-normalised features (B, T, 262), before the fusion."""
        mask = torch.ones(z.shape[0], num_frames, dtype=torch.bool, device=z.device)
        return self.normalizer.denormalize(self.vae.decode(z, mask))

    def _canonical_actor(self, actor: np.ndarray) -> tuple[torch.Tensor, RigidTransform]:
        """The actor (T, 22, 3) in its canonical frame, and the map into that frame (the
        actor was checked by ``check_actor`` first: shape, length, finite, body-sized)."""
        joints = torch.from_numpy(np.ascontiguousarray(actor, dtype=np.float32))
        frame = canonical_transform(joints)
        return frame.apply(joints), frame

    def _encode(self, features: torch.Tensor) -> torch.Tensor:
        """Posterior means (B, p, r) of de-normalised features (B, T, 262)."""
        x = self.normalizer.normalize(features).to(self.device)
        mask = torch.ones(x.shape[:2], dtype=torch.bool, device=self.device)
        return self.vae.encode(x, mask)[0]

    def _encode_actor(self, features: torch.Tensor, batch: int) -> torch.Tensor:
        """Latent (batch, p, r) of the canonical actor's features (T, 262): posterior mean."""
        return self._encode(features[None]).expand(batch, -1, -1)


def default_model_dir() -> Path:
    """Where the bundled model lives inside the installed package."""
    return Path(__file__).parent / "assets" / "model"


class _TextDim:
    """Stands in for the text encoder where only its width matters (dry-run builds)."""

    def __init__(self, dim: int) -> None:
        self.dim = dim


def dry_run_build(config: Any, text_dim: int = 384) -> dict[str, Any]:
    """Build VAE, P-Flow and S-Flow on the ``meta`` device (no memory) and return them.

    Catches configs that cannot be built (heads not dividing widths, token counts the
    pyramid cannot halve ...) and ones too big to allocate, before anything is allocated.
    """
    try:
        with torch.device("meta"):  # build's default normaliser: the dry run never reads it
            pipe = UMFPipeline.build(config, None, _TextDim(text_dim))
    except UMFError:
        raise
    except Exception as exc:  # construction raises many types for bad sizes
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UMFError(f"the model config cannot be built: {msg}") from exc
    modules = {"vae": pipe.vae, "pflow": pipe.pflow, "sflow": pipe.sflow}
    total = sum(
        t.numel() * t.element_size()
        for m in modules.values()
        for t in [*m.parameters(), *m.buffers()]
    )
    if total > MAX_MODEL_BYTES:
        raise UMFError(
            f"the model config describes {total / 2**30:.1f} GiB of weights "
            f"(at most {MAX_MODEL_BYTES / 2**30:.0f} GiB)"
        )
    return modules


def check_model_config(config: Any, text_dim: int = 384) -> dict[str, Any]:
    """Values first (types, ranges), then a dry-run build; returns the meta modules."""
    check_config_values(config)
    return dry_run_build(config, text_dim)
