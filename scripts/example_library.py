"""Write the worked example of docs/teach.md: a small mocap library in the layout
`umf data prepare --mocap` reads, made from the repository's sample clips.

    python scripts/example_library.py out/example-library

Four Bandai sample clips rewritten as Mixamo rigs (``mixamorig:`` joint names, centimetres,
60 fps), a captions.csv with wordings of its own, and a takes.csv that pairs two of them as
one "take". That take is constructed (two solo clips placed 1.6 m apart, facing each other),
not captured together: it shows the file format, not real interaction. The clips are
CC BY-NC 4.0 (Bandai-Namco-Research-Motiondataset), like everything made from them.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "bandai-sample" / "Bandai-Namco-Research-Motiondataset-1" / "data"
CLIPS = {  # sample clip -> (file in the library, captions, label)
    "dataset-1_bow_normal_001": (
        "solo/greeting_bow.bvh",
        ["A man bows deeply.", "Someone greets with a formal bow."],
        "bow",
    ),
    "dataset-1_kick_normal_001": (
        "solo/front_kick.bvh",
        ["A fighter kicks forward.", "Someone throws a kick."],
        "kick",
    ),
    "dataset-1_call_normal_001": ("pair/caller.bvh", [], "call"),
    "dataset-1_respond_normal_001": ("pair/answer.bvh", [], "respond"),
}
TAKE = ("call-and-answer", ["One person calls out and the other answers.",
                            "Someone calls to a friend, who responds."])  # fmt: skip


def write_mixamo(path: Path, joints: np.ndarray, fps: float) -> None:
    """SMPL-22 joints (T, 22, 3) in metres as a Mixamo-named BVH in centimetres."""
    from umf.bvh import write_bvh
    from umf.data.skeletons import SKELETONS
    from umf.skeleton import PARENTS, fit_offsets, inverse_kinematics

    j = torch.from_numpy(joints).double()
    offsets = fit_offsets(j)
    local = inverse_kinematics(j, offsets).numpy()
    names = [f"mixamorig:{n}" for n in SKELETONS["mixamo"]]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bvh(path, names, PARENTS, offsets.numpy() * 100, local, j[:, 0].numpy() * 100,
              1.0 / fps)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    args = ap.parse_args()

    from umf.data.bandai import resample
    from umf.data.motion_file import load_motion

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    placed = {}
    for clip, (name, _, _) in CLIPS.items():
        joints = load_motion(SAMPLE / f"{clip}.bvh").joints[0]
        placed[name] = joints
    # the constructed take: the answer 1.6 m in front of the caller, turned to face them
    a, b = placed["pair/caller.bvh"], placed["pair/answer.bvh"]
    t = min(len(a), len(b))
    b = b[:t].copy()
    b[..., [0, 2]] = -(b[..., [0, 2]] - b[:1, :1, [0, 2]])  # half a turn about the start
    b[..., [0, 2]] += a[:1, :1, [0, 2]] + np.array([0.0, 1.6])
    placed["pair/caller.bvh"], placed["pair/answer.bvh"] = a[:t], b
    for name, joints in placed.items():
        j60 = resample(joints[None].astype(np.float32), 30.0, 60.0)[0]
        write_mixamo(out / name, j60.astype(np.float64), 60.0)
    with open(out / "captions.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "caption", "label"])
        for name, captions, label in CLIPS.values():
            for c in captions:
                w.writerow([name, c, label])
        for c in TAKE[1]:
            w.writerow([TAKE[0], c, "call-answer"])
    with open(out / "takes.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["take", "file", "person"])
        w.writerow([TAKE[0], "pair/caller.bvh", 1])
        w.writerow([TAKE[0], "pair/answer.bvh", 2])
    (out / "README.md").write_text(
        "Example mocap library made by scripts/example_library.py from the Bandai sample "
        "clips (CC BY-NC 4.0, Bandai-Namco-Research-Motiondataset, (c) 2022 Bandai Namco "
        "Research Inc.). The take call-and-answer is constructed, not captured together.\n"
    )
    print(f"example library written to {out}")


if __name__ == "__main__":
    main()
