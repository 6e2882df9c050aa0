"""A salsa couple seed by seed: the "teach it" issue's salsa targets on one model, fast.

    python research/salsa_seeds.py [MODEL_DIR] [--seeds 8] [--first 0] [--warm-take W ...]

"Two people dance salsa together.", 4 s, delivered: per seed the closeness statistics of
``research/teach_report.py`` (nearest hands within 0.3 x stature: the share of frames;
pelvises apart in statures; facing: the median cosine; the body capsules' overlap), then
their medians and the seeds passing every target. ``teach_report.py`` measures the real
takes beside them. ``--warm-take``: the same seeds again for each value of
``sflow.warm_take`` (a sweep; the medians only), ``--first``: the first seed (the bundled
model's 0.7 was chosen on seeds 8-23, results/umf-small-bandai-20261213). ``--nearest
CORPUS``: how far each couple is from the training takes, its mean per-joint distance to
the nearest crop of the model's bank (both people as the pipeline decodes them, in person
1's frame), beside the real test and val takes' first 4 s against the same crops: a couple
finished from a crop stays near it, a new real couple does not. ``--json FILE``: every
seed's statistics, for ``research/salsa_figure.py``. ``--real-crops CORPUS``: how many 4 s
crops of the real salsa takes (every 30 frames) pass the same targets, take by take and per
split: real couples dance apart too, so "every seed passes" is more than real salsa does.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from teach_report import SALSA, closeness, salsa_pass


def salsa_couples(model: Path | None, seeds: int, first: int = 0, warm_take: float | None = None):
    """(seed, joints (2, T, 22, 3) as delivered) of "Two people dance salsa together.", 4 s,
    seeds first..first+seeds-1, from the model directory (None: the bundled model), with
    ``sflow.warm_take`` set to ``warm_take`` (None: the model's own)."""
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    if warm_take is not None:
        pipe.config.sflow.warm_take = warm_take
    for s in range(first, first + seeds):
        (scene,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
        yield s, np.asarray(scene.joints, dtype=np.float64)


def take_crops(model: Path | None, frames: int = 120) -> np.ndarray:
    """The bank's touching-take crops of ``frames`` decoded as the pipeline decodes a scene:
    joints (N, 2, T + 1, 22, 3) in person 1's frame."""
    import torch

    from umf.pipeline import UMFPipeline
    from umf.representation import features_to_joints

    pipe = UMFPipeline.from_pretrained(model)
    z = pipe.reactions.takes[frames]
    with torch.no_grad():
        raw = pipe._decode_raw(z.flatten(0, 1).to(pipe.device), frames).reshape(
            len(z), 2, frames, -1
        )
        feats = torch.cat([pipe._fuse(raw[:, :1]), pipe._fuse(raw[:, 1:], reaction=True)], dim=1)
    return features_to_joints(feats.cpu()).numpy()


def nearest_crop(joints: np.ndarray, crops: np.ndarray) -> float:
    """Mean per-joint distance (m) of a couple (2, T, 22, 3) to the nearest of ``crops``."""
    t = min(joints.shape[1], crops.shape[2])
    return float(
        np.linalg.norm(crops[:, :, :t] - joints[None, :, :t], axis=-1).mean((1, 2, 3)).min()
    )


MEDIANS = ("hands_near", "pelvis", "facing", "penetration_cm", "penetration_frac")


def crops_passing(joints: np.ndarray, frames: int = 121, every: int = 30) -> list[bool]:
    """Whether each crop of ``frames`` (4 s and one), started every ``every`` frames, of a
    real couple (2, T, 22, 3) passes the salsa targets (:func:`salsa_pass`)."""
    starts = range(0, joints.shape[1] - frames + 1, every)
    return [salsa_pass(closeness(joints[:2, s : s + frames])) for s in starts]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path, nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--warm-take", type=float, nargs="+", default=None)
    ap.add_argument("--nearest", type=Path, default=None, metavar="CORPUS")
    ap.add_argument("--real-crops", type=Path, default=None, metavar="CORPUS")
    ap.add_argument("--json", type=Path, default=None, help="every seed's statistics, per "
                    "warm_take (research/salsa_figure.py draws them)")  # fmt: skip
    args = ap.parse_args()

    if args.real_crops is not None:
        from umf.data.corpus import Corpus

        split: dict[str, list[bool]] = {}
        for c in Corpus.load(args.real_crops).clips:
            if c.meta.get("content") == "salsa":
                got = crops_passing(c.joints)
                split.setdefault(c.split, []).extend(got)
                print(f"{c.id} ({c.split}): {sum(got)} of {len(got)} 4 s crops pass")
        for name, got in sorted(split.items()):
            print(f"{name}: {sum(got)} of {len(got)} ({np.mean(got):.0%})")
        return

    if args.nearest is not None:
        from umf.data.corpus import Corpus
        from umf.representation import canonicalize_scene

        crops = take_crops(args.model)
        near = [
            nearest_crop(j, crops) for _, j in salsa_couples(args.model, args.seeds, args.first)
        ]
        print("generated, seed by seed:", " ".join(f"{d:.3f}" for d in near),
              f"m; median {np.median(near):.3f}")  # fmt: skip
        import torch

        for c in Corpus.load(args.nearest).clips:
            if c.meta.get("content") == "salsa" and c.split in ("test", "val"):
                canon, _ = canonicalize_scene(torch.from_numpy(c.joints[:2, :121]).float())
                print(f"real {c.split} {c.id}: {nearest_crop(canon.numpy(), crops):.3f} m")
        return

    every = []
    for take in args.warm_take or [None]:
        rows = []
        for s, joints in salsa_couples(args.model, args.seeds, args.first, take):
            c = closeness(joints)
            rows.append(c)
            every.append({"warm_take": take, "seed": s, **c, "pass": salsa_pass(c)})
            if args.warm_take is None:
                print(s, {k: round(v, 3) if isinstance(v, float) else v for k, v in c.items()},
                      salsa_pass(c))  # fmt: skip
        if take is not None:
            print(f"warm_take {take}:", end=" ")
        print(", ".join(f"{k} median {np.median([r[k] for r in rows]):.3f}" for k in MEDIANS)
              + f"; passing {sum(salsa_pass(r) for r in rows)} / {args.seeds}")  # fmt: skip
    if args.json is not None:
        import json

        args.json.write_text(json.dumps(every, indent=1) + "\n")


if __name__ == "__main__":
    main()
