"""Re-roll one person of a scene: everyone else exactly as they were, person k anew.

S-Flow adds a person as a reaction to a context of people (paper Sec. 4.2.2); here the
context is everybody but person k, as delivered. Their joints are moved into the canonical
frame of the first of them (person 1, or person 2 when person 1 is re-rolled), encoded by
the VAE (posterior means, as in S-Flow's training), and S-Flow samples person k with the
scene's prompt. Person 1 is re-rolled the same way, as a reaction to the others: P-Flow
takes no context, so a new person 1 from it would ignore everyone who reacted to the old
one. The new person goes through the pipeline's clean-up on its own (anchored, shifted
apart from the others, fitted, and with a prompt worded like a touching take its bones
moved out of the others', :mod:`umf.untangle`); the others' joints, bodies and features are
copied.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from umf.anchoring import anchor_people
from umf.errors import UMFError
from umf.kinematics import Bodies, fit_bodies
from umf.person_prompts import person_text
from umf.representation import (
    CONTACT,
    assemble_features,
    canonical_transform,
    features_to_joints_integrated,
    joints_to_rot6d,
    transform_features,
)
from umf.scene import Scene
from umf.separation import separate_people, touching_distances
from umf.streams import scene_generators
from umf.text import respell_prompt
from umf.untangle import untangle
from umf.validation import check_int, check_request, check_text
from umf.warm_start import mirror_text, sample_added


def check_reroll(scene: Scene, person: int, fps: float, max_frames: int) -> None:
    """A scene of 2+ people at the model's frame rate and length, and a person of it."""
    if not isinstance(scene, Scene):
        raise UMFError(f"reroll takes a Scene, got {type(scene).__name__}")
    n = scene.num_people
    if n < 2:
        raise UMFError("a one-person scene has nobody to react to: generate it again with "
                       "another seed")  # fmt: skip
    check_int("person", person, 1, n)
    if abs(scene.fps - fps) > 1e-6:
        raise UMFError(f"the scene is at {scene.fps:g} fps, the model at {fps:g}")
    if not 16 <= scene.num_frames <= max_frames + 1:
        raise UMFError(f"the scene must have 16..{max_frames + 1} frames to be re-rolled, "
                       f"got {scene.num_frames}")  # fmt: skip
    if not np.isfinite(scene.joints).all():
        raise UMFError("the scene's joints contain NaN or infinite values")


def reroll_person(
    pipe: Any,
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
    """``scene`` with person ``person`` (1-based) sampled again by ``pipe``'s S-Flow from
    ``seed``; see the module docstring. ``prompt`` defaults to the scene's own text,
    ``person_prompt`` (what this person does) to the one the scene recorded for them."""
    cfg = pipe.config
    check_reroll(scene, person, cfg.fps, cfg.vae.max_frames)
    if prompt is not None and not isinstance(prompt, str):
        raise UMFError(f"the prompt must be a string, got {prompt!r:.60}")
    if seed is None:
        raise UMFError("seed must be an integer, got None")
    if prompt is None and not scene.text.strip():
        raise UMFError("the scene has no prompt: give one")
    text = scene.text if prompt is None else prompt
    # the bounds of any generation request, checked where pipe() checks them
    req = check_request(text, scene.num_people, seed=seed, guidance=guidance,
                        sflow_steps=sflow_steps)  # fmt: skip
    text, seed, guidance = req.prompts[0], req.seed, req.guidance
    n, k = scene.num_people, person - 1
    own_all = list(scene.meta.get("person_prompts") or [None] * n)
    own_all += [None] * (n - len(own_all))
    if person_prompt is not None:
        own_all[k] = check_text(person_prompt, "person prompt")
        pipe.check_person_prompts([own_all[k]])
    # a prompt the scene recorded is used by a model that takes them, else left aside
    own = own_all[k] if isinstance(own_all[k], str) and pipe.person_prompts else None
    steps = req.sflow_steps or cfg.sflow.steps_for(n)
    others = [i for i in range(n) if i != k]
    joints = torch.from_numpy(np.ascontiguousarray(scene.joints, dtype=np.float32))
    frame = canonical_transform(joints[others[0]])
    placed = frame.apply(joints[others])  # (N - 1, T, 22, 3)
    feats = torch.stack([assemble_features(j, joints_to_rot6d(j)) for j in placed])
    t = feats.shape[1]  # T joint frames are T - 1 feature frames
    device = pipe.device
    with torch.no_grad():
        context = pipe._encode(feats.to(device))[None]  # (1, N - 1, p, r)
        mask = torch.ones(context.shape[:2], dtype=torch.bool, device=device)
        words = respell_prompt(text, cfg.text.respell)
        cond = pipe.text_encoder.encode([words]).to(device)
        uncond = pipe.text_encoder.encode([""]).to(device)
        person_kw = person_text(pipe, [own], 0, 1)
        w, _ = sample_added(
            pipe, context, mask, cond, uncond, t, steps=steps,
            guidance=cfg.sflow.guidance if guidance is None else guidance,
            generator=scene_generators(seed, [0], device), own=person_kw,
            pflow_guidance=guidance, mirror=mirror_text(pipe, [words]),
            answers_first=k > 0,  # a re-rolled person 1 answers nobody
            last=k == n - 1,  # a file's walker re-rolled inside it is not sent to its end
        )  # fmt: skip
        new = transform_features(pipe.decode(w, t, reaction=True)[0].cpu(), frame, inverse=True)
    decoded = features_to_joints_integrated(new).numpy()  # (T, 22, 3), one frame added
    contacts = new[:, CONTACT].numpy()
    contacts = np.concatenate([contacts, contacts[-1:]])  # the added frame keeps the last's
    floor = float(scene.meta.get("floor", 0.0))
    start = anchor_people(decoded[None], contacts[None], floor) if anchor else decoded[None]
    shift = np.zeros(3, dtype=np.float32)
    near = None
    if separate:  # the new person last: only its shift is taken, the others stay put
        near = (pipe.coverage([text])[0] or {}).get("contact")
        order = np.concatenate([scene.joints[others], start])
        _, shifts = separate_people(order, **touching_distances(near))
        shift = shifts[-1]
    moved = start + shift
    body = fit_bodies(moved, contacts[None], floor, True)
    if near and scene.bodies is not None:  # as the clean-up does: out of the others' bodies
        b = scene.bodies
        group = Bodies(*(np.concatenate([getattr(b, f)[others], getattr(body, f)])
                         for f in ("offsets", "rotations", "root")))  # fmt: skip
        group = untangle(group, [False] * len(others) + [True], floor)
        body = Bodies(group.offsets[-1:], group.rotations[-1:], group.root[-1:])
    out_joints = scene.joints.copy()
    out_joints[k] = body.joints()[0]
    raw = (scene.raw_joints if scene.raw_joints is not None else scene.joints).copy()
    raw[k] = decoded + shift
    features = None
    if scene.features is not None and scene.features.shape[1] in (t, t + 1):
        features = scene.features.copy()
        row = new.numpy()
        row[:, :66] += np.tile(shift, 22)
        features[k, : row.shape[0]] = row
        if features.shape[1] > row.shape[0]:
            features[k, row.shape[0] :] = row[-1]
    bodies = None
    if scene.bodies is not None:
        b = scene.bodies
        bodies = Bodies(b.offsets.copy(), b.rotations.copy(), b.root.copy())
        bodies.offsets[k], bodies.rotations[k], bodies.root[k] = (
            body.offsets[0], body.rotations[0], body.root[0])  # fmt: skip
    entry = {"person": person, "seed": seed, "prompt": text}
    if own is not None:
        entry["person_prompt"] = own
    rerolls = [*scene.meta.get("rerolled", []), entry]
    meta = {**scene.meta, "rerolled": rerolls}
    if any(isinstance(p, str) for p in own_all):
        meta["person_prompts"] = own_all
        meta["person_coverage"] = [None if not isinstance(p, str) else pipe.coverage([p])[0]
                                   for p in own_all]  # fmt: skip
    if "shifts" in meta and len(meta["shifts"]) == n:
        meta["shifts"] = [list(s) for s in meta["shifts"]]
        meta["shifts"][k] = shift.tolist()
    return Scene(out_joints, features, scene.text, scene.fps, scene.seed, pipe.name, meta, raw,
                 bodies, fit=False)  # fmt: skip
