"""How far the VAE moves a real person's pelvis: real test clips against their reconstructions.

People who should stand still (waving, raising hands, bowing) drift across the floor in
generated motion. This script asks whether the drift comes from the VAE: it encodes and
decodes the real single-person clips of each label in a split (test unless ``--split``;
posterior mean, then the pipeline's position fusion at the model's ``root_fusion`` or at
the values given), and prints the medians over clips of

* ``path``: the pelvis's horizontal path length over the duration (m/s; what
  ``umf.eval.motion_stats``'s ``pelvis_speed`` measures, jitter included),
* ``net``: the straight-line distance from the first to the last frame over the duration
  (m/s; drift, no jitter),
* ``ankles``: root-relative ankle speed (m/s; the legs' motion).

``--delivered`` adds each source as the pipeline would hand it out (planted feet anchored,
:func:`umf.pipeline.delivered_joints`, with the clip's own contact labels): how much of the
drift, and of the travel, survives anchoring.

    python research/vae_root_drift.py [MODEL_DIR] [--labels wave-right-hand walk ...]
        [--root-fusion 0.005 0.05] [--delivered] [--split test] [--corpus out/corpus]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from umf.data.corpus import Corpus
from umf.eval.motion_stats import PELVIS, motion_statistics
from umf.eval.protocol import corpus_items
from umf.eval.reconstruction import reconstruct
from umf.pipeline import UMFPipeline, delivered_joints
from umf.representation import CONTACT, features_to_joints

LABELS = ("raise-up-both-hands", "wave-right-hand", "bow", "walk", "run")


def drift(features: np.ndarray, fps: float = 30.0, delivered: bool = False
          ) -> tuple[float, float, float]:  # fmt: skip
    """(path speed, net speed, ankle speed) of one person's raw features (T, 262), as
    decoded or (``delivered``) with its planted feet anchored."""
    f = np.asarray(features)
    j = features_to_joints(torch.as_tensor(f).float()).numpy()
    if delivered:
        j = delivered_joints(j[None], f[None, :, CONTACT])[0]
    stats = motion_statistics(j, fps)  # pelvis_speed: the path, jitter included
    pelvis = j[:, PELVIS, [0, 2]].astype(np.float64)
    net = np.linalg.norm(pelvis[-1] - pelvis[0]) / (max(len(j) - 1, 1) / fps)
    return stats["pelvis_speed"], float(net), stats["ankle_energy"]


def item_label(item) -> str | None:
    """A single-person item's content label (its key is (label, style))."""
    return item.key[0] if isinstance(item.key, tuple) else item.key


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default="src/umf/assets/model")
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--labels", nargs="+", default=list(LABELS))
    ap.add_argument("--root-fusion", nargs="+", type=float, default=None)
    ap.add_argument("--max-clips", type=int, default=40)
    ap.add_argument("--split", default="test", help="test, val or train (seen in training)")
    ap.add_argument("--delivered", action="store_true", help="also as the pipeline delivers")
    args = ap.parse_args()
    torch.set_num_threads(2)
    pipe = UMFPipeline.from_pretrained(args.model)
    items = corpus_items(Corpus.load(args.corpus), args.split, "single")
    weights = args.root_fusion or [pipe.vae.cfg.root_fusion]
    print("| label | clips | source | path (m/s) | net (m/s) | ankles (m/s) |")
    print("|---|---:|---|---:|---:|---:|")
    for label in args.labels:
        real = [it.features[0][: pipe.config.vae.max_frames] for it in items
                if item_label(it) == label][: args.max_clips]  # fmt: skip
        if not real:
            print(f"| {label} | 0 | no {args.split} clips | | | |")
            continue
        rows = [("real", real)]
        for w in weights:
            rec = reconstruct(pipe.vae, pipe.normalizer, real, root_fusion=w)
            rows.append((f"VAE, root_fusion {w:g}", rec))
        for name, clips in rows:
            for delivered in (False, True) if args.delivered else (False,):
                med = np.median(np.array([drift(f, delivered=delivered) for f in clips]), axis=0)
                shown = f"{name}, delivered" if delivered else name
                print(f"| {label} | {len(clips)} | {shown} | {med[0]:.3f} | {med[1]:.3f} | "
                      f"{med[2]:.3f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
