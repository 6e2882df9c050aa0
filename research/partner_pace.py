"""Why runners side by side fell behind: each follower's pace at every step of its warm start,
and where it starts beside the others.

    python research/partner_pace.py [MODEL_DIR] [--seeds 8] [--people 2 3]

For "Two / Three people run side by side." (4 s, seeds 0..N-1), per follower: person 1's floor
speed (start to end), the first pass's, the warm start's proposal's (the retrieved reaction
as the second pass starts from it, played at person 1's pace with ``sflow.warm_play``) and
the raw result's, with where the retrieved reaction starts (x, z in person 1's frame: +x is
person 1's left). The second pass keeps its proposal's pace, so a follower is as fast as the
reaction it was given; and a third runner retrieved beside person 1 took person 2's spot
(results/umf-small-bandai-20261212).
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

PROMPTS = {2: "Two people run side by side.", 3: "Three people run side by side."}


def chord_speed(joints: np.ndarray, fps: float) -> np.ndarray:
    """(P,) each person's pelvis floor speed start to end (m/s), joints (P, T, 22, 3)."""
    p = joints[:, :, 0][..., [0, 2]]
    return np.linalg.norm(p[:, -1] - p[:, 0], axis=-1) * fps / (p.shape[1] - 1)


def trace(pipe, prompt: str, people: int, seed: int) -> tuple[np.ndarray, list[dict]]:
    """The raw scene's speeds and, per follower, what its warm start saw."""
    import umf.warm_start as ws

    fps, steps = pipe.config.fps, []
    real_proposal, real_pick = ws.proposal, pipe.reactions.pick

    def pick(*args, **kwargs):
        length, idx, fits = real_pick(*args, **kwargs)
        steps.append({"start": pipe.reactions.starts[length][idx[0]].tolist()})
        return length, idx, fits

    def proposal(p, first, decoded, *args, **kwargs):
        z, nfe, fits, waits, straight = real_proposal(p, first, decoded, *args, **kwargs)
        played = p.decode(z, decoded.shape[1], reaction=True)
        steps[-1] |= {"first": float(ws.floor_velocity(decoded, fps)[0].norm()),
                      "proposal": float(ws.floor_velocity(played, fps)[0].norm()),
                      "fits": bool(fits[0])}  # fmt: skip
        return z, nfe, fits, waits, straight

    ws.proposal, pipe.reactions.pick = proposal, pick
    try:
        (scene,) = pipe(prompt, num_people=people, seconds=4.0, seed=seed)
    finally:
        ws.proposal, pipe.reactions.pick = real_proposal, real_pick
    return chord_speed(np.asarray(scene.raw_joints), fps), steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--people", type=int, nargs="+", default=[2, 3], choices=[2, 3])
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model)
    if pipe.reactions is None:
        raise SystemExit(f"error: {pipe.name} has no reaction bank (umf train reactions)")
    print(f"model {pipe.name}; m/s start to end: person 1 | per follower: first pass -> "
          f"proposal -> raw, where its reaction starts (x, z)")  # fmt: skip
    for n in args.people:
        for seed in range(args.seeds):
            speed, steps = trace(pipe, PROMPTS[n], n, seed)
            rows = [f"{s['first']:.2f} -> {s['proposal']:.2f} -> {v:.2f} "
                    f"({s['start'][0]:+.2f}, {s['start'][1]:+.2f})"
                    + ("" if s["fits"] else " first pass kept")
                    for s, v in zip(steps, speed[1:], strict=True)]  # fmt: skip
            print(f"{n} people, seed {seed}: {speed[0]:.2f} | " + " | ".join(rows))


if __name__ == "__main__":
    main()
