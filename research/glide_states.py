"""Where does the followers' glide come from: the S-Flow's predictions on the states it
trains on, or on the states its own sampler reaches? (the "reactions that keep up" issue)

    python research/glide_states.py [--model DIR] --corpus DIR [--scenes 16] [--seed 0]

Real test pairs of "walk side by side" (the corpus's scene items in person 1's frame, the
crop the S-Flow trains on): person 1's latent is the context, person 2's the real reaction W.
For each, the reaction the S-Flow's (guided) prediction points at, x_t + (1 - t) v, at
t = 0.25, 0.5 and 0.75,

- on the training path: x_t = t W + (1 - t) (C + sigma eps') in the reaction half (what the
  loss and ``train_sflow.foot_loss`` see);
- on the sampler's path: x_t reached by the pipeline's Euler steps (4 for pairs) from
  [eps || C + sigma eps'];

the sampled reaction at t = 1, and the reaction sampled from a warm start (the reaction half
at t0 = 0.25 or 0.5 on the training path towards another pair's real follower, or towards
the P-Flow's own walker for the caption; with the pelvis's distance to the real follower's
and to the leader's: where the warm start puts person 2). Each is
decoded (fused as the pipeline delivers people 2..N) and scored against the real W's
decode: the planted feet's excess speed (m/frame, the foot loss), the pelvis's floor speed
and the slower foot's speed (m/s; a stride keeps one foot near 0, a glide carries both).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

TIMES = (0.25, 0.5, 0.75)


def speeds(joints: torch.Tensor, fps: float) -> tuple[float, float]:
    """Median over rows of the pelvis floor speed and the slower ankle's floor speed (m/s)."""
    v = (joints[:, 1:, :, [0, 2]] - joints[:, :-1, :, [0, 2]]).norm(dim=-1) * fps
    pelvis = v[:, :, 0].mean(1)
    slower = torch.minimum(v[:, :, 7], v[:, :, 8]).mean(1)
    return float(pelvis.median()), float(slower.median())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--scenes", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from umf.data.corpus import Corpus
    from umf.flows import (
        classifier_free_guidance,
        reaction_endpoint,
        semi_noise_state,
    )
    from umf.flows.solvers import integrate
    from umf.models.pflow import encode_uncond
    from umf.pipeline import UMFPipeline
    from umf.representation import features_to_joints
    from umf.train.datasets import SceneDataset
    from umf.train.foot_slide import decoded_foot_slide
    from umf.warm_start import move_onto

    pipe = UMFPipeline.from_pretrained(args.model)
    sflow, cfg = pipe.sflow.eval(), pipe.config
    corpus = Corpus.load(args.corpus)
    ds = SceneDataset(corpus, "test", corpus.normalizer, min_frames=120, max_frames=120,
                      mirror=False, seed=args.seed)  # fmt: skip
    walks = [i for i, (kind, item, _) in enumerate(ds.items)
             if kind == "scene" and item["relation"] == "walk_side_by_side"]  # fmt: skip
    picks = walks[: args.scenes]
    items = [ds[i] for i in picks]
    feats = torch.stack([it["features"] for it in items])  # (B, 2, T, 262), normalised
    b, _, frames, _ = feats.shape
    mask = torch.ones(b, frames, dtype=torch.bool)
    g = torch.Generator().manual_seed(args.seed)
    with torch.no_grad():
        z = torch.stack([pipe.vae.encode(feats[:, k], mask)[0] for k in range(2)], dim=1)
        prev, w = sflow.latent_norm.normalize(z[:, :1]), sflow.latent_norm.normalize(z[:, 1])
        context = sflow.context(prev, torch.ones(b, 1, dtype=torch.bool))
        text = pipe.text_encoder.encode([it["caption"] for it in items])
        cond = {"text": sflow.net.encode_text(text)}
        uncond = {"text": encode_uncond(sflow.net, pipe.text_encoder.encode([""] * b), b)}
        guided = classifier_free_guidance(sflow.velocity, cfg.sflow.guidance, cond, uncond)

        def field(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
            return guided(x, t, context=context)  # read by sflow.context_condition

        sigma = cfg.sflow.reaction_noise
        eps = torch.randn(context.shape, generator=g)
        start = context + sigma * torch.randn(context.shape, generator=g)
        x0 = torch.cat([eps, start], dim=-1)  # semi_noise_initial_state, its noises shared
        steps = cfg.sflow.steps_for(2)
        fusion = cfg.vae.fusion_weights(reaction=True)

        def features(lat: torch.Tensor) -> torch.Tensor:
            """S-Flow-normalised latents decoded as the pipeline delivers people 2..N."""
            return pipe.decode(sflow.latent_norm.denormalize(lat), frames, reaction=True)

        def decoded(lat: torch.Tensor) -> torch.Tensor:
            return features_to_joints(features(lat))

        def score(name: str, lat: torch.Tensor) -> None:
            slide = decoded_foot_slide(pipe.vae, pipe.normalizer, sflow.latent_norm.denormalize(w),
                                       sflow.latent_norm.denormalize(lat), torch.ones(b),
                                       min_t=0.0, rows=b, frames=frames, fusion=fusion)  # fmt: skip
            pelvis, slower = speeds(decoded(lat), cfg.fps)
            print(f"  {name:28s} slide {float(slide) * 1000:5.1f} mm/frame   pelvis "
                  f"{pelvis:.2f} m/s   slower foot {slower:.2f} m/s")  # fmt: skip

        leader = decoded(prev[:, 0])

        def placed(lat: torch.Tensor) -> None:
            """Where person 2 is: from the real follower's pelvis, and from the leader's
            (floor distance, median over rows of the mean over frames)."""
            p2 = decoded(lat)[:, :, 0, [0, 2]]
            real = (p2 - decoded(w)[:, :, 0, [0, 2]]).norm(dim=-1).mean(1).median()
            lead = (p2 - leader[:, :, 0, [0, 2]]).norm(dim=-1).mean(1).median()
            print(f"    pelvis {float(real):.2f} m from the real follower's, "
                  f"{float(lead):.2f} m from the leader's")  # fmt: skip

        print(f"model {pipe.name}; {b} real test pairs walking side by side, {frames} frames, "
              f"{steps} S-Flow steps, guidance {cfg.sflow.guidance}")  # fmt: skip
        score("real W (decoded)", w)
        for t in TIMES:
            tt = torch.full((b,), t)
            s = semi_noise_state(context, w, eps, tt, reaction_start=start)
            score(f"training path, t = {t}", reaction_endpoint(s.x, field(s.x, tt), tt))
            k = round(t * steps)
            if abs(k / steps - t) < 1e-9:
                xs, _ = integrate(field, x0, steps=k, t0=0.0, t1=t) if k else (x0, 0)
                score(f"sampler path, t = {t}", reaction_endpoint(xs, field(xs, tt), tt))
        x1, _ = integrate(field, x0, steps=steps)
        score("sampled (t = 1)", x1[..., x1.shape[-1] // 2 :])
        # a warm start: the reaction half at t0 already on its way to another pair's real
        # follower (a sharp walk that knows nothing of this leader), the rest of the steps
        # from there
        other = w.roll(1, dims=0)
        # the same from the P-Flow's own walker for the scene's caption (multi-person token):
        # a sharp walk the model itself makes, standing where person 1 starts
        own, _ = pipe.pflow.sample(text, pipe.text_encoder.encode([""] * b), dataset=1,
                                   generator=g)  # fmt: skip
        own = sflow.latent_norm.normalize(own)
        # ... and moved, rigidly on the floor, to where the blur of the S-Flow's first step
        # starts (its first-frame pelvis and facing), then encoded again
        blur = reaction_endpoint(x0, field(x0, torch.zeros(b)), torch.zeros(b))
        moved = move_onto(features(own), features(blur))
        placed_own = sflow.latent_norm.normalize(pipe._encode(moved))
        guesses = (("another follower", other), ("P-Flow's walker", own),
                   ("P-Flow's walker, placed", placed_own))  # fmt: skip
        for name, guess in guesses:
            for t0 in (0.25, 0.5):
                s = semi_noise_state(context, guess, eps, torch.full((b,), t0),
                                     reaction_start=start)  # fmt: skip
                k = steps - round(t0 * steps)
                xw, _ = integrate(field, s.x, steps=k, t0=t0, t1=1.0)
                react = xw[..., xw.shape[-1] // 2 :]
                score(f"warm: {name}, t0 {t0}", react)
                placed(react)
        print("  sampled:", end="")
        placed(x1[..., x1.shape[-1] // 2 :])
        print("  real:", end="")
        placed(w)


if __name__ == "__main__":
    main()
