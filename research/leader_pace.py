"""Would the warm start's retrieval overshoot less if it also matched each real reaction's own
leader to the generated leader? (the "reactions that keep up" issue; not in the package)

    python research/leader_pace.py --corpus out/corpus [--model DIR] [--weights 0 1 2 4]

For the model's bank (built from ``--corpus``'s train scenes with the same draws as
``umf train reactions``), each reaction's leader speed is measured: person 1's start-to-end
floor speed in the same crop. Then, for each weight w, the velocity gap the retrieval and
its pace check use becomes sqrt(|v_bank - v_first|^2 + (w |lead_bank - lead_generated|)^2),
with the generated person 1's decoded speed, and ``research/keep_pace.py`` runs (seeds 0-7).
w = 0 is the model as shipped. This patches ``umf.reaction_bank`` and ``umf.pipeline`` in
this process only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def leader_speeds(pipe, corpus_dir: Path) -> dict[int, torch.Tensor]:
    """Per stored length, the leader speed of each reaction of the model's bank (the draws of
    ``umf.train.reactions.build_reaction_bank``, checked against the stored velocities)."""
    from umf.data.corpus import Corpus
    from umf.train.datasets import SceneDataset
    from umf.warm_start import floor_velocity

    corpus, rng, out = Corpus.load(corpus_dir), np.random.default_rng(0), {}

    def speed(xs: list[torch.Tensor]) -> torch.Tensor:
        return floor_velocity(pipe.normalizer.denormalize(torch.stack(xs)), pipe.config.fps)

    for frames in pipe.reactions.lengths():
        ds = SceneDataset(corpus, "train", pipe.normalizer, min_frames=frames,
                          max_frames=frames, mirror=True, seed=0)  # fmt: skip
        leaders, people = [], []
        for i in range(len(ds)):
            f = ds[i]["features"]
            if f.shape[1] == frames:
                people.extend(f[1:])
                leaders.extend([f[0]] * (f.shape[0] - 1))
        keep = np.sort(rng.permutation(len(people))[: len(pipe.reactions.latents[frames])])
        mine = speed([people[i] for i in keep])
        if not torch.allclose(mine, pipe.reactions.velocities[frames], atol=2e-2):
            raise SystemExit(f"error: the bank of {frames} frames is not {corpus_dir}'s")
        out[frames] = speed([leaders[i] for i in keep]).norm(dim=-1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 1.0, 2.0, 4.0])
    args = ap.parse_args()

    import keep_pace

    import umf.pipeline
    import umf.reaction_bank
    import umf.warm_start
    from umf.pipeline import UMFPipeline

    lead = leader_speeds(UMFPipeline.from_pretrained(args.model), args.corpus)
    state: dict = {}
    added, gap = umf.warm_start.sample_added, umf.reaction_bank.ReactionBank._gap

    def sample_added(pipe, prev, mask, text, uncond, frames, **kw):
        p1 = pipe.decode(prev[:, 0], frames)
        state["lead"] = umf.warm_start.floor_velocity(p1, pipe.config.fps).norm(dim=-1)
        return added(pipe, prev, mask, text, uncond, frames, **kw)

    def led_gap(self, length, velocity):
        g = gap(self, length, velocity)
        dl = (lead[length].to(g)[None] - state["lead"].to(g)[:, None]).abs()
        return (g**2 + (state["w"] * dl) ** 2).sqrt()

    umf.pipeline.sample_added = sample_added
    umf.reaction_bank.ReactionBank._gap = led_gap
    for w in args.weights:
        state["w"] = w
        print(f"== leader weight {w}")
        rows = keep_pace.measure(args.model, 8)
        for key, row in rows.items():
            print(f"  {key}: {row['seeds_meeting_target']}/8 meet the target, delivered "
                  f"{row['delivered_ratio_median']:.2f}x the leader")  # fmt: skip


if __name__ == "__main__":
    main()
