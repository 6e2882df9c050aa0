"""Where a salsa couple's hands are lost: the real takes, the VAE's reconstruction of them,
the S-Flow's partner beside a real leader, and the whole model.

    python research/salsa_bounds.py CORPUS [--model DIR] [--seeds 2]
        [--train-crops-only [--sflow-steps S] [--guidance G]] [--push-only]

4-second segments (121 frames, every 5 s, at most 4 per take) of the corpus's real salsa
takes, in person 1's frame at their first frame; per row the medians of
``research/teach_report.py``'s closeness statistics (hands near: the share of frames with
some wrists within 0.3 x stature; pelvises apart in statures; facing: the median cosine),
and the overlap (the mean share of frames whose bodies overlap by more than 1 cm):

1. the real couples;
2. both people encoded and decoded by the model's VAE (posterior mean, decoded as the
   pipeline decodes person 1 and people 2..N): what any flow of this VAE could give at best;
3. person 1 real, person 2 the model's (``pipe(..., actor=leader)``, seeds 0..N-1); and
   the same without the separation pass (``separate=False``), which moves a person rigidly
   until no frame is too close;
4. both generated ("Two people dance salsa together.", seeds 0-7; ``salsa_seeds.py``);
5. the S-Flow's person 2 (with its sampler's warm start, raw decode, no clean-up) beside
   the real leader of the train takes' crops as the S-Flow's loader serves them (120 frames,
   4 crops per take, person 1's posterior mean as the context): what it learned of the
   takes it trained on, with nothing between.

Rows 1-3 for the train takes (seen in training) and the test and val takes (not seen).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from teach_report import SALSA, closeness

KEYS = ("hands_near", "pelvis", "facing")


def segments(take) -> list[np.ndarray]:
    """(2, 121, 22, 3) windows of a take, 5 s apart, at most 4."""
    joints = take.joints
    return [np.ascontiguousarray(joints[:, s : s + 121])
            for s in range(0, joints.shape[1] - 121, 150)][:4]  # fmt: skip


def reconstructed(pipe, couple: np.ndarray) -> np.ndarray:
    """Both people through the VAE in person 1's frame, decoded as the pipeline decodes."""
    import torch

    from umf.representation import (
        canonicalize_scene,
        features_to_joints,
        fuse_positions,
        joints_to_features,
    )

    canon, _ = canonicalize_scene(torch.from_numpy(couple).float())
    x = torch.stack([joints_to_features(canon[k]) for k in range(2)])
    mask = torch.ones(x.shape[:2], dtype=torch.bool)
    with torch.no_grad():
        mu, _ = pipe.vae.encode(pipe.normalizer.normalize(x), mask)
        y = pipe.normalizer.denormalize(pipe.vae.decode(mu, mask))
    vae = pipe.config.vae
    y = torch.stack([fuse_positions(y[k], *vae.fusion_weights(reaction=k > 0)) for k in range(2)])
    return features_to_joints(y).numpy()


def training_crops(pipe, corpus) -> tuple[list[dict], list[dict]]:
    """Row 5 (module notes): closeness of the real crops and of the S-Flow's partners."""
    import torch

    from umf.representation import features_to_joints
    from umf.train.datasets import SceneDataset
    from umf.warm_start import sample_added

    ds = SceneDataset(corpus, "train", pipe.normalizer, min_frames=120, max_frames=120,
                      mirror=False, seed=0, real_repeats=4)  # fmt: skip
    ds.items = [it for it in ds.items
                if it[0] == "clip" and "salsa" in " ".join(it[1].captions).lower()]  # fmt: skip
    text, uncond = pipe.text_encoder.encode([SALSA]), pipe.text_encoder.encode([""])
    real, generated = [], []
    for i in range(len(ds)):
        f = ds[i]["features"]  # normalised (2, 120, 262), person 1's frame
        if f.shape[1] != 120:
            continue
        with torch.no_grad():
            lead = pipe.vae.encode(f[:1], torch.ones(1, 120, dtype=torch.bool))[0]
            w, _ = sample_added(pipe, lead[:, None], torch.ones(1, 1, dtype=torch.bool), text,
                                uncond, 120, steps=pipe.config.sflow.steps_for(2),
                                guidance=pipe.config.sflow.guidance,
                                generator=[torch.Generator().manual_seed(i)], own={},
                                pflow_guidance=None)  # fmt: skip
            partner = features_to_joints(pipe.decode(w, 120, reaction=True)[0]).numpy()
        people = features_to_joints(pipe.normalizer.denormalize(f)).numpy()
        real.append(closeness(people))
        generated.append(closeness(np.stack([people[0], partner])))
    return real, generated


def beside_real(pipe, couples: list[np.ndarray], seeds: int, separate: bool) -> list[dict]:
    """Row 3: each real leader with the model's partner, seeds 0..seeds-1, delivered."""
    return [closeness(np.asarray(pipe(SALSA, num_people=2, seed=s, actor=c[0],
                                      separate=separate)[0].joints))
            for c in couples for s in range(seeds)]  # fmt: skip


def medians(rows: list[dict]) -> str:
    """The closeness medians, and the bodies' overlap: the mean share of frames in which the
    two people's capsules overlap by more than 1 cm (``umf.eval.physics``)."""
    out = ", ".join(f"{k} {np.median([r[k] for r in rows]):.3f}" for k in KEYS)
    return f"{out}, overlap {np.mean([r['penetration_frac'] for r in rows]):.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=2, help="seeds per real leader (row 3)")
    ap.add_argument("--train-crops-only", action="store_true", help="row 5 alone")
    ap.add_argument("--sflow-steps", type=int, default=None, help="the S-Flow's steps for pairs")
    ap.add_argument("--guidance", type=float, default=None, help="the S-Flow's guidance")
    ap.add_argument("--push-only", action="store_true",
                    help="the separation's push without its shortest-shift search (as "
                    "before umf-small-bandai-20261207's session)")  # fmt: skip
    args = ap.parse_args()
    if args.push_only:
        import umf.separation

        umf.separation.DIRECTIONS = 0  # no direction is searched: the push stays

    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    if args.sflow_steps is not None:
        pipe.config.sflow.pair_steps = args.sflow_steps
    if args.guidance is not None:
        pipe.config.sflow.guidance = args.guidance
    corpus = Corpus.load(args.corpus)
    if args.train_crops_only:
        real, partners = training_crops(pipe, corpus)
        print(f"train crops ({len(real)}), real: {medians(real)}")
        print(f"the S-Flow's partner (pair steps {pipe.config.sflow.steps_for(2)}, guidance "
              f"{pipe.config.sflow.guidance}): {medians(partners)}")  # fmt: skip
        return
    takes = [c for c in corpus.clips
             if c.num_people == 2 and "salsa" in " ".join(c.captions).lower()]  # fmt: skip
    print(f"model {pipe.name}; {len(takes)} salsa takes")
    for name, splits in (("train takes", {"train"}), ("test and val takes", {"test", "val"})):
        couples = [s for t in takes if t.split in splits for s in segments(t)]
        if not couples:
            continue
        real = [closeness(c) for c in couples]
        vae = [closeness(reconstructed(pipe, c)) for c in couples]
        beside, unseparated = (beside_real(pipe, couples, args.seeds, sep) for sep in (True, False))
        print(f"{name} ({len(couples)} segments of 4 s):")
        print(f"  1. real couples:                    {medians(real)}")
        print(f"  2. VAE reconstruction of both:      {medians(vae)}")
        print(f"  3. real leader, generated partner:  {medians(beside)}")
        print(f"     the same, no separation pass:   {medians(unseparated)}")
    gen = [closeness(np.asarray(pipe(SALSA, num_people=2, seconds=4.0, seed=s)[0].joints))
           for s in range(8)]  # fmt: skip
    print(f"4. both generated, seeds 0-7:        {medians(gen)}")
    real, partners = training_crops(pipe, corpus)
    print(f"5. train crops ({len(real)}), real:             {medians(real)}")
    print(f"   the same leaders, the S-Flow's partner: {medians(partners)}")


if __name__ == "__main__":
    main()
