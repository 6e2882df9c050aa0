"""The glide of walking followers against the S-Flow's sampling settings, and where person
2's variety comes from (the experiments of results/umf-small-bandai-20261204).

    python research/reaction_knobs.py [--model DIR] [--corpus CORPUS]

- knobs: "Two people walk side by side.", seeds 0-5, 4 s, with S-Flow steps 4 or 16, the
  reaction start's noise at 0.5, guidance 1 or 4 (each row changes one setting from the
  model's); medians of person 2 / person 1 floor speed, decoded and delivered, and where
  person 2 ends along the leader's heading (m);
- spread (with ``--corpus``): person 2 reacting to 3 real test walkers (``actor``), seeds
  0-3: the mean distance of its joints to their mean over seeds, with the reaction start's
  noise as trained and at 0 (only the context half's noise left).
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from keep_pace import pace

WALK = "Two people walk side by side."


@contextmanager
def sflow_set(pipe, **change):
    """S-Flow options changed in place (the S-Flow module reads the reaction start's noise
    from the same config object the pipeline holds), restored after."""
    cfg = pipe.config.sflow
    old = {k: getattr(cfg, k) for k in change}
    for k, v in change.items():
        setattr(cfg, k, v)
    try:
        yield
    finally:
        for k, v in old.items():
            setattr(cfg, k, v)


def knobs(pipe) -> None:
    rows = {"as trained": {}, "16 steps": {"pair_steps": 16, "steps": 16},
            "start noise 0.5": {"reaction_noise": 0.5}, "guidance 1": {"guidance": 1.0},
            "guidance 4": {"guidance": 4.0}}  # fmt: skip
    for name, change in rows.items():
        out = []
        with sflow_set(pipe, **change):
            for s in range(6):
                (sc,) = pipe(WALK, num_people=2, seconds=4.0, seed=s)
                raw, _ = pace(np.asarray(sc.raw_joints), pipe.config.fps)
                v, ahead = pace(np.asarray(sc.joints), pipe.config.fps)
                out.append((raw[1] / raw[0], v[1] / v[0], ahead[1]))
        dec, dlv, ahead = np.median(np.array(out), axis=0)
        print(f"{name:16s} person 2 / leader: decoded {dec:.2f}, delivered {dlv:.2f}; "
              f"ends {ahead:+.2f} m ahead")  # fmt: skip


def spread(pipe, corpus_dir: Path) -> None:
    from umf.data.corpus import Corpus

    walks = [c for c in Corpus.load(corpus_dir).split_clips("test")
             if c.meta.get("content") == "walk" and c.num_frames > 121][:3]  # fmt: skip
    for sigma in (pipe.config.sflow.reaction_noise, 0.0):
        spreads = []
        with sflow_set(pipe, reaction_noise=sigma):
            for clip in walks:
                f = np.stack([np.asarray(pipe(WALK, num_people=2, seed=s,
                                              actor=clip.joints[0, :121])[0].raw_joints[1])
                              for s in range(4)])  # fmt: skip
                spreads.append(float(np.linalg.norm(f - f.mean(0), axis=-1).mean()))
        print(f"reaction start noise {sigma}: person 2's spread over seeds 0-3, "
              f"{len(walks)} real leaders: {np.round(spreads, 2)} m")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None)
    args = ap.parse_args()
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    knobs(pipe)
    if args.corpus is not None:
        spread(pipe, args.corpus)


if __name__ == "__main__":
    main()
