"""Does the VAE keep *when* an action starts? The timing part of the reactions issue.

A bow back must start after the bow it answers (the relation check ``starts_after``); the
S-Flow learns latents of the VAE, so a delay the VAE does not keep, no flow can give.

1. ``shift``: real single clips of a few labels, each held still at its first pose for
   0, 10, ... 40 frames before it plays (:func:`umf.representation.shift_in_time`, the
   length kept), encoded (posterior mean) and decoded as the pipeline decodes people 2..N.
   Printed per label and shift: the median action onset
   (:func:`umf.data.relations.action_onset`) of the input and of its reconstruction, read
   frame to frame and on positions averaged over ``ONSET_SMOOTHING`` frames (the checks'
   reading).
2. ``scenes``: the split's composed scenes with a ``starts_after`` check (bow back, call and
   respond, spar ...), every person encoded and decoded on their own (person 1 as person 1,
   the others as reactions): the share of checks passed by the real scenes and by their
   reconstructions under both readings, with the lags (frames from person 1's onset to
   person 2's, the checks' reading).

3. ``wrist``: the right wrist of real raised right hands held still for 0-40 frames, input
   and reconstruction: the first frame it is 10 cm above where it started (median over
   clips). No reading of motion energy, so no shimmer: the wait survives the round trip.

4. ``readings`` (``--readings``): the readings of an onset the checks could use, scored as
   ``ONSET_SMOOTHING`` was chosen: averages over 1, 9, 15, 21 frames and "the pose has moved
   a tenth / a fifth of the way to its furthest from its first frame" (on raw positions and
   on 9-frame averages). For each: the share of ``starts_after`` checks passed by the real
   scenes and by their round trips (test, val, the first 100 train scenes with the check),
   and over held clips of every label of the test and val splits (shifts 0-40) the median
   and 90th-percentile gap between the onset of input and reconstruction.

Decoded motion shimmers a few mm per joint per frame; read frame to frame, that shimmer
over a still second outweighs a bow, and every reconstruction "starts" 12-16 frames in.

    python research/vae_timing.py [MODEL_DIR] [--corpus CORPUS] [--split test] [--readings]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from umf.data.corpus import Corpus
from umf.data.relations import ONSET_SMOOTHING, action_onset, check, moving_average
from umf.pipeline import UMFPipeline, default_model_dir
from umf.representation import canonicalize_features, features_to_joints, shift_in_time

RIGHT_WRIST = 21
LABELS = ("bow", "call", "kick", "raise-up-right-hand", "wave-both-hands")
SHIFTS = (0, 10, 20, 30, 40)


def onset(features: torch.Tensor, smooth: int = 1) -> int:
    return action_onset(features_to_joints(features.float()).numpy(), smooth=smooth)


def round_trip(pipe: UMFPipeline, features: torch.Tensor, reaction: bool) -> torch.Tensor:
    """Features (B, T, 262) encoded (posterior mean) and decoded as the pipeline decodes."""
    return pipe.decode(pipe._encode(features), features.shape[1], reaction=reaction)


def label_clips(corpus: Corpus, splits: list[str], label: str, frames: int,
                clips: int) -> torch.Tensor | None:  # fmt: skip
    """Features (B, frames, 262), canonical, of up to ``clips`` single-person clips of
    ``label`` longer than ``frames`` in ``splits``, in order; None where there are none."""
    chosen = [c for split in splits for c in corpus.split_clips(split)
              if c.num_people == 1 and c.meta.get("content") == label
              and c.num_frames > frames + 1][:clips]  # fmt: skip
    if not chosen:
        return None
    return torch.stack([canonicalize_features(torch.from_numpy(corpus.clip_features(c))[0]
                                              .float()[:frames]) for c in chosen])  # fmt: skip


def shift_table(pipe: UMFPipeline, corpus: Corpus, split: str, frames: int, clips: int) -> None:
    print(f"1. clips held still before they play ({frames} frames, up to {clips} per label, "
          f"{split}): median onset, input -> reconstruction")  # fmt: skip
    for label in LABELS:
        base = label_clips(corpus, [split], label, frames, clips)
        if base is None:
            continue
        for smooth in (1, ONSET_SMOOTHING):
            cells = []
            for s in SHIFTS:
                held = torch.stack([shift_in_time(f, s) for f in base])
                back = round_trip(pipe, held, reaction=True)
                cells.append(f"+{s}: {np.median([onset(f, smooth) for f in held]):.0f} -> "
                             f"{np.median([onset(f, smooth) for f in back]):.0f}")  # fmt: skip
            print(f"  {label:20s} ({len(base)}) averaged over {smooth}: " + " | ".join(cells))


def wrist_table(pipe: UMFPipeline, corpus: Corpus, split: str, frames: int, clips: int) -> None:
    chosen = [c for c in corpus.split_clips(split)
              if c.num_people == 1 and c.meta.get("content") == "raise-up-right-hand"
              and c.num_frames > frames + 1][:clips]  # fmt: skip
    if not chosen:
        return
    base = torch.stack([canonicalize_features(torch.from_numpy(corpus.clip_features(c))[0]
                                              .float()[:frames]) for c in chosen])  # fmt: skip

    def rises(features: torch.Tensor) -> float:
        wrist = features_to_joints(features.float())[..., RIGHT_WRIST, 1].numpy()  # (B, T)
        up = wrist - wrist[:, :1] > 0.10
        return float(np.median([np.argmax(u) if u.any() else len(u) for u in up]))

    cells = []
    for s in SHIFTS:
        held = torch.stack([shift_in_time(f, s) for f in base])
        cells.append(f"+{s}: {rises(held):.0f} -> {rises(round_trip(pipe, held, True)):.0f}")
    print(
        f"3. right wrist 10 cm up, raised right hands ({len(chosen)}), input -> "
        "reconstruction: " + " | ".join(cells)
    )


def scene_table(pipe: UMFPipeline, corpus: Corpus, split: str) -> None:
    recipes = [r for r in corpus.scenes[split]
               if any(c["type"] == "starts_after" for c in r["constraints"])]  # fmt: skip
    real_ok, back_ok, lags, frame_to_frame = [], [], [], []
    for r in recipes:
        f = torch.from_numpy(corpus.scene_features(r)).float()
        back = torch.cat([round_trip(pipe, f[:1], reaction=False),
                          round_trip(pipe, f[1:], reaction=True)])  # fmt: skip
        real_j, back_j = (features_to_joints(x).numpy() for x in (f, back))
        for c in r["constraints"]:
            if c["type"] == "starts_after":
                real_ok.append(check(real_j, c).passed)
                back_ok.append(check(back_j, c).passed)
                raw = [action_onset(j[c["b"]]) - action_onset(j[c["a"]]) for j in (real_j, back_j)]
                frame_to_frame.append([x >= c["min_frames"] for x in raw])
                lag = [int(check(j, c).value) for j in (real_j, back_j)]
                lags.append((r["relation"], c["min_frames"], *lag))
    ftf = np.mean(frame_to_frame, axis=0)
    print(
        f"2. {split} scenes with a starts_after check: {len(recipes)} scenes, {len(real_ok)} "
        f"checks; passed: real {np.mean(real_ok):.3f}, VAE round trip {np.mean(back_ok):.3f} "
        f"(read frame to frame: real {ftf[0]:.3f}, round trip {ftf[1]:.3f})"
    )
    for rel in sorted({x[0] for x in lags}):
        rows = [x for x in lags if x[0] == rel]
        print(f"  {rel:14s} ({len(rows)}): needed (median) {np.median([x[1] for x in rows]):.0f}"
              f", real lag {np.median([x[2] for x in rows]):.0f}, reconstructed lag "
              f"{np.median([x[3] for x in rows]):.0f} frames")  # fmt: skip


def moved_onset(joints: np.ndarray, share: float, smooth: int = 1) -> int:
    """The first frame the pose (relative to the pelvis) is ``share`` of the way to its
    furthest from the first frame (mean over joints)."""
    local = moving_average(joints - joints[:, :1], smooth)
    away = np.linalg.norm(local - local[:1], axis=-1).mean(-1)
    return 0 if away.max() <= 1e-8 else int(np.argmax(away >= share * away.max()))


READINGS = {
    "frame to frame": lambda j: action_onset(j),
    "averaged over 9": lambda j: action_onset(j, smooth=9),
    "averaged over 15": lambda j: action_onset(j, smooth=15),
    "averaged over 21": lambda j: action_onset(j, smooth=21),
    "a tenth of the way": lambda j: moved_onset(j, 0.1),
    "a fifth of the way": lambda j: moved_onset(j, 0.2),
    "a tenth, averaged over 9": lambda j: moved_onset(j, 0.1, 9),
    "a fifth, averaged over 9": lambda j: moved_onset(j, 0.2, 9),
}


def readings_table(pipe: UMFPipeline, corpus: Corpus, frames: int, clips: int) -> None:
    print("4. readings of an onset: starts_after passed, real / round trip, per split; "
          "held clips: |onset(input) - onset(reconstruction)| median / 90th pct")  # fmt: skip
    passed = {name: {} for name in READINGS}
    for split, most in (("test", None), ("val", None), ("train", 100)):
        recipes = [r for r in corpus.scenes[split]
                   if any(c["type"] == "starts_after" for c in r["constraints"])]  # fmt: skip
        recipes = recipes[:most]
        got = {name: ([], []) for name in READINGS}
        for r in recipes:
            f = torch.from_numpy(corpus.scene_features(r)).float()
            back = torch.cat([round_trip(pipe, f[:1], reaction=False),
                              round_trip(pipe, f[1:], reaction=True)])  # fmt: skip
            scenes = [features_to_joints(x).numpy() for x in (f, back)]
            for c in (c for c in r["constraints"] if c["type"] == "starts_after"):
                for name, read in READINGS.items():
                    for i, j in enumerate(scenes):
                        got[name][i].append(read(j[c["b"]]) - read(j[c["a"]]) >= c["min_frames"])
        for name in READINGS:
            passed[name][split] = (np.mean(got[name][0]), np.mean(got[name][1]), len(recipes))
    gaps = {name: [] for name in READINGS}
    for label in sorted({c.meta.get("content") for c in corpus.clips if c.num_people == 1}):
        base = label_clips(corpus, ["test", "val"], label, frames, clips)
        if base is None:
            continue
        for s in SHIFTS:
            held = torch.stack([shift_in_time(f, s) for f in base])
            pairs = zip(*(features_to_joints(x).numpy()
                          for x in (held, round_trip(pipe, held, True))), strict=True)  # fmt: skip
            for a, b in pairs:
                for name, read in READINGS.items():
                    gaps[name].append(abs(read(a) - read(b)))
    for name in READINGS:
        cells = " | ".join(f"{split} ({n}) {real:.2f} / {back:.2f}"
                           for split, (real, back, n) in passed[name].items())  # fmt: skip
        g = gaps[name]
        print(f"  {name:26s} {cells} | held {np.median(g):.0f} / {np.percentile(g, 90):.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--corpus", default="out/corpus")
    ap.add_argument("--split", default="test")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--clips", type=int, default=8)
    ap.add_argument("--readings", action="store_true", help="also compare onset readings (4.)")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model or default_model_dir())
    corpus = Corpus.load(args.corpus)
    print(f"model {pipe.name}, corpus {args.corpus}")
    shift_table(pipe, corpus, args.split, args.frames, args.clips)
    scene_table(pipe, corpus, args.split)
    wrist_table(pipe, corpus, args.split, args.frames, args.clips)
    if args.readings:
        readings_table(pipe, corpus, args.frames, 6)


if __name__ == "__main__":
    main()
