"""What S-Flow is handed as context: the flows' own latents or their re-encoding.

    python research/context_reencode.py [--model DIR] [--seeds 8]

For the model as it is and with ``sflow.reencode_context`` on, seeds 0..N-1, 4 s:
- how far the decoded person 1 starts from the frame S-Flow trained in (the origin,
  facing +Z): the offset (m) and the turn (degrees) of ``leader_frame``, for a salsa, a
  kick and a walk prompt;
- "Two people dance salsa together.": the teach report's closeness (research/teach_report.py)
  on the decoded positions;
- "Two people walk side by side.": person 2's delivered and decoded floor speed over the
  leader's;
- the same with re-encoding but person 1 left where it was decoded (not re-centred);
- with ``--corpus``, each real salsa take's leader (its first 4 s) as person 1 of a
  reaction (``umf react``), seeds 0-1: where the S-Flow puts the follower around a real one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from teach_report import SALSA, closeness

from umf.pipeline import UMFPipeline
from umf.representation import RigidTransform, leader_frame

FRAME_PROMPTS = (SALSA, "One person kicks toward the other, who steps back.",
                 "Two people walk side by side.")  # fmt: skip
WALK = "Two people walk side by side."


def speed(j: np.ndarray) -> float:
    p = j[:, 0, [0, 2]]
    return float(np.linalg.norm(p[-1] - p[0]) / ((len(p) - 1) / 30))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--corpus", type=Path, default=None, help="the salsa takes for reactions")
    args = ap.parse_args()
    pipe = UMFPipeline.from_pretrained(args.model)
    seeds = range(args.seeds)
    print(f"model {pipe.name}; {args.seeds} seeds, 4 s")
    for prompt in FRAME_PROMPTS:
        off, turn = [], []
        for s in seeds:
            (sc,) = pipe(prompt, num_people=2, seconds=4.0, seed=s)
            tf = leader_frame(torch.from_numpy(np.asarray(sc.features[0])))
            off.append(float(np.hypot(tf.origin[0], tf.origin[2])))
            turn.append(abs(float(np.degrees(tf.yaw))))
        span = f"{min(off):.2f}-{max(off):.2f} m, {min(turn):.0f}-{max(turn):.0f} degrees"
        print(f"person 1's start off the training frame, {prompt!r}: {span}")
    import umf.pipeline

    centred = umf.pipeline.leader_frame
    for flag, recentre in ((False, True), (True, True), (True, False)):
        pipe.config.sflow.reencode_context = flag
        # re-encoding alone: person 1 left where it was decoded
        umf.pipeline.leader_frame = (
            centred if recentre else lambda f: RigidTransform(0.0, (0, 0, 0))
        )
        rows = []
        for s in seeds:
            (sc,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
            c = closeness(np.asarray(sc.raw_joints))
            rows.append((c["hands_near"], c["pelvis"], c["facing"]))
        h, p, f = np.median(np.array(rows), axis=0)
        pace = []
        for s in seeds:
            (sc,) = pipe(WALK, num_people=2, seconds=4.0, seed=s)
            j, r = np.asarray(sc.joints), np.asarray(sc.raw_joints)
            pace.append((speed(j[1]) / speed(j[0]), speed(r[1]) / speed(r[0])))
        pace_a = np.array(pace)
        name = f"reencode_context={flag}" + ("" if recentre else ", not re-centred")
        print(f"{name}: salsa medians hands_near {h:.2f}, pelvis/stature "
              f"{p:.2f}, facing {f:.2f}; walk, person 2 / leader speed delivered "
              f"{np.median(pace_a[:, 0]):.2f} ({pace_a[:, 0].min():.2f}-{pace_a[:, 0].max():.2f}), "
              f"decoded {np.median(pace_a[:, 1]):.2f}")  # fmt: skip
    umf.pipeline.leader_frame = centred
    pipe.config.sflow.reencode_context = False
    if args.corpus is not None:
        from umf.data.corpus import Corpus

        apart = []
        for c in Corpus.load(args.corpus).clips:
            if c.meta.get("content") == "salsa":
                for s in range(2):
                    (sc,) = pipe(SALSA, num_people=2, seed=s, actor=c.joints[0, : 4 * 30 + 1])
                    apart.append(closeness(np.asarray(sc.raw_joints))["pelvis"])
        print(
            f"reactions to {len(apart) // 2} real salsa leaders, seeds 0-1: pelvises "
            f"{min(apart):.2f}-{max(apart):.2f} statures apart (median {np.median(apart):.2f})"
        )


if __name__ == "__main__":
    main()
