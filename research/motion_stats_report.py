"""Motion statistics of generated single people per label, for one or more models.

16 people per label from the label's prompt, 4 s, seed 0, raw decoded motion (no fit),
against the corpus's real clips of that label (``umf.eval.motion_stats``); the same check
as ``umf eval``'s section 5 without the rest of the evaluation. ``--delivered`` scores the
people as the default pipeline hands them out instead (feet anchored, bodies fitted: the
"delivered" rows of ``umf eval``). ``--reconstructed`` scores, instead of generated people,
the label's real clips (at most 64 per label, evenly spaced over the corpus, so mostly
training clips; whole, up to 300 frames) encoded and decoded by the model's VAE: what its
latents can give at best, raw or, with ``--delivered``, as the pipeline delivers them.

    python research/motion_stats_report.py MODEL_DIR [MODEL_DIR ...] [--delivered]
        [--reconstructed] [--corpus out/corpus]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from umf.data.corpus import Corpus
from umf.eval import motion_stats as MS
from umf.eval.reconstruction import reconstruct
from umf.pipeline import UMFPipeline, delivered_joints
from umf.representation import CONTACT, features_to_joints

RECONSTRUCTED = 64  # real clips per label


def reconstructions(pipe: UMFPipeline, corpus: Corpus, label: str, delivered: bool) -> list:
    """The label's real clips (at most RECONSTRUCTED, evenly spaced over the corpus order,
    which groups styles; each whole up to 300 frames, as the real range takes them) through
    the VAE as the pipeline decodes (``umf.eval.reconstruction.reconstruct``): joints
    (T, 22, 3) each, raw or as the pipeline delivers them."""
    clips = MS.real_clips_by_label(corpus, labels=[label]).get(label, [])
    if len(clips) > RECONSTRUCTED:
        clips = [
            clips[i] for i in np.linspace(0, len(clips) - 1, RECONSTRUCTED).round().astype(int)
        ]
    feats = [corpus.clip_features(clip)[0][:300] for clip in clips]
    out = []
    for decoded in reconstruct(pipe.vae, pipe.normalizer, feats):
        joints = features_to_joints(torch.as_tensor(decoded)).numpy()
        if delivered:
            joints = delivered_joints(joints[None], decoded[None, :, CONTACT])[0]
        out.append(joints)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--delivered", action="store_true", help="score the pipeline's output")
    ap.add_argument("--reconstructed", action="store_true",
                    help="score the VAE's reconstructions of real clips")  # fmt: skip
    args = ap.parse_args()
    torch.set_num_threads(2)
    corpus = Corpus.load(args.corpus)
    real = MS.real_joints_by_label(corpus)
    by_prompt = {prompt: label for label, (prompt, _) in MS.LABELS.items()}
    for path in args.models:
        pipe = UMFPipeline.from_pretrained(path)

        def generate(prompt: str, n: int, pipe: UMFPipeline = pipe) -> list:
            if args.reconstructed:
                return reconstructions(pipe, corpus, by_prompt[prompt], args.delivered)
            scenes = pipe([prompt] * n, num_people=1, seconds=4.0, seed=0, fit=args.delivered)
            return [s.joints[0] for s in scenes]  # fit=False: joints are the raw positions

        rows = MS.check_labels(real, generate, samples=args.samples)
        kind, passes = ("delivered" if args.delivered else "raw"), MS.label_passes(rows)
        kind += ", real clips reconstructed" if args.reconstructed else ""
        print(f"## {path} ({kind}): {sum(passes.values())}/{len(passes)}")
        print(MS.format_checks(rows), flush=True)


if __name__ == "__main__":
    main()
