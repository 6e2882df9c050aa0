"""Measure what the pipeline's clean-up does to generated scenes: anchoring planted feet
(umf.anchoring) and the kinematic fit (umf.kinematics).

For each prompt (the README's examples, seed 0, bundled model), decoded (``scene.raw_joints``)
against delivered (``scene.joints``): bone-length spread within a person (max - min of
each bone over time, the worst bone), foot skating (mean horizontal speed of a foot joint
while its decoded contact label says planted, and the evaluation's skate ratio), floor
penetration (per frame the depth of the lowest joint below the floor; mean and max), the
distance of the delivered pose to the decoded one (root-relative), how far anchoring moved
a person's end point, the SMPL mapping residual and the clean-up's time.

    python scripts/fit_report.py [--model DIR]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from umf import UMFPipeline
from umf.eval.physics import foot_skating
from umf.exports.smpl import mapping_residual
from umf.kinematics import FOOT_JOINTS
from umf.representation import CONTACT
from umf.skeleton import bone_lengths

PROMPTS = [
    ("A person walks forward.", 1), ("Someone waves with the right hand.", 1),
    ("A person raises both hands.", 1), ("Someone bows politely.", 1),
    ("A person runs forward.", 1), ("One person bows and the other bows back.", 2),
    ("Two people walk side by side.", 2), ("Three people walk side by side.", 3),
    ("A person calls and four people walk over to them.", 5),
]  # fmt: skip


def spread_cm(joints: np.ndarray) -> np.ndarray:
    """Per person, the largest max - min of a bone's length over time (cm)."""
    lengths = bone_lengths(torch.from_numpy(joints.astype(np.float64)))
    return ((lengths.max(1).values - lengths.min(1).values).max(-1).values * 100).numpy()


def skating(joints: np.ndarray, contacts: np.ndarray, fps: float) -> float:
    """Mean horizontal speed (m/s) of foot joints over the steps labelled planted."""
    feet = joints[:, :, list(FOOT_JOINTS)][..., [0, 2]]
    speed = np.linalg.norm(np.diff(feet, axis=1), axis=-1) * fps
    planted = contacts[:, :-1] > 0.5
    return float(speed[planted].mean()) if planted.any() else 0.0


def speed(joints: np.ndarray, fps: float = 30.0) -> np.ndarray:
    """Per person (N,), the pelvis's floor distance from first to last frame per second."""
    span = np.linalg.norm(joints[:, -1, 0, [0, 2]] - joints[:, 0, 0, [0, 2]], axis=-1)
    return span * fps / (joints.shape[1] - 1)


def depth_cm(joints: np.ndarray, floor: float) -> tuple[float, float]:
    depth = np.clip(floor - joints[..., 1].min(-1), 0.0, None) * 100
    return float(depth.mean()), float(depth.max())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    pipe = UMFPipeline.from_pretrained(args.model)
    rows, travel = [], []
    for prompt, n in PROMPTS:
        t0 = time.perf_counter()
        pipe(prompt, num_people=n, seconds=4.0, seed=0, fit=False, separate=False)  # no clean-up
        t1 = time.perf_counter()
        s = pipe(prompt, num_people=n, seconds=4.0, seed=0)[0]  # what users get
        seconds = time.perf_counter() - t1 - (t1 - t0)
        raw, contacts, floor, out = s.raw_joints, s.features[..., CONTACT], 0.0, s.joints
        pose = np.linalg.norm((out - out[:, :, :1]) - (raw - raw[:, :, :1]), axis=-1)
        moved = np.linalg.norm((out - raw)[:, -1, 0, [0, 2]], axis=-1).max()
        travel.append((prompt, [speed(x) for x in (raw, out)]))
        ratio = [np.mean([foot_skating(j, s.fps)["skate_ratio"] for j in x]) for x in (raw, out)]
        res = np.concatenate([mapping_residual(s.bodies, i).ravel() for i in range(n)])
        rows.append((prompt, n, spread_cm(raw).max(), spread_cm(out).max(),
                     skating(raw, contacts, s.fps), skating(out, contacts, s.fps), *ratio,
                     *depth_cm(raw, floor), *depth_cm(out, floor), pose.mean() * 1000,
                     pose.max() * 1000, moved, res.mean() * 1000, res.max() * 1000,
                     seconds))  # fmt: skip
    head = (
        "prompt | N | bone spread cm raw / out | skate m/s raw / out | skate ratio raw / out | "
        "floor depth cm mean/max raw | out | pose change mm mean / max | end moved m | "
        "SMPL residual mm mean / max | clean-up s"
    )
    print(head)
    for r in rows:
        print(f"{r[0][:40]} | {r[1]} | {r[2]:.1f} / {r[3]:.4f} | {r[4]:.3f} / {r[5]:.3f} | "
              f"{r[6]:.3f} / {r[7]:.3f} | {r[8]:.2f}/{r[9]:.2f} | {r[10]:.2f}/{r[11]:.2f} | "
              f"{r[12]:.1f} / {r[13]:.1f} | {r[14]:.2f} | {r[15]:.1f} / {r[16]:.1f} | "
              f"{r[17]:.2f}")  # fmt: skip
    a = np.array([r[2:] for r in rows], dtype=float)
    print(
        "mean | | {:.1f} / {:.4f} | {:.3f} / {:.3f} | {:.3f} / {:.3f} | {:.2f}/{:.2f} | "
        "{:.2f}/{:.2f} | {:.1f} / {:.1f} | {:.2f} | {:.1f} / {:.1f} | {:.2f}".format(*a.mean(0))
    )
    print("\nprompt | travel m/s per person (start to end on the floor), decoded -> delivered")
    for prompt, (before, after) in travel:
        pairs = ", ".join(f"{x:.2f} -> {y:.2f}" for x, y in zip(before, after, strict=True))
        print(f"{prompt[:40]} | {pairs}")


if __name__ == "__main__":
    main()
