"""What a model learnt from the real mocap: salsa couples, new actions, against real takes.

    python research/teach_report.py [--model DIR] [--corpus out/corpus] [--seeds 8] [--out FILE]

Measured on delivered scenes (``scene.joints``, after the clean-up) and on the decoder's raw
positions, seeds 0..N-1, 4 s each (the targets of the "teach it" issue):
- "Two people dance salsa together.": nearest hands within 0.3 x stature in at least half
  the frames, pelvises 0.25-1.0 x stature apart (median), facing each other (median cosine
  above 0.5); the same statistics of the real salsa takes of the corpus's test and val splits;
- a cartwheel and a backflip turn the body over (head below the pelvis at some frame), a jump
  lifts the pelvis at least 15 cm above its median, a crawl keeps the pelvis below 0.6 m (90th
  percentile), getting up starts with the pelvis below 0.4 m and ends standing (head above
  1.2 m over the last 10 frames), and getting up again at 3 s, the real clip's own length;
- with ``--corpus``, the same checks on the VAE's reconstructions of the DeepMimic clips
  (whether the VAE can hold an action at all, before any flow is asked for it).
Prints a table and writes JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SALSA = "Two people dance salsa together."
ACTIONS = {
    "cartwheel": "A person does a cartwheel.",
    "backflip": "A person does a backflip.",
    "jump": "A person jumps up.",
    "crawl": "A person crawls on hands and knees.",
    "getup": "A person lying face down gets up.",
}


def action_check(kind: str, j: np.ndarray) -> tuple[bool, float]:
    """(passes, the measured value) for one person's joints (T, 22, 3)."""
    pelvis, head = j[:, 0, 1], j[:, 15, 1]
    if kind in ("cartwheel", "backflip"):
        v = float((head - pelvis).min())
        return v < 0, v
    if kind == "jump":
        v = float(pelvis.max() - np.median(pelvis))
        return v >= 0.15, v
    if kind == "crawl":
        v = float(np.percentile(pelvis, 90))
        return v < 0.6, v
    if kind == "getup":
        start, end = float(pelvis[:5].mean()), float(head[-10:].mean())
        return start < 0.4 and end > 1.2, start
    raise ValueError(kind)


def closeness(joints: np.ndarray) -> dict:
    """pair_closeness plus the body capsules' overlap (umf.eval.physics): mean depth over
    frames and the fraction of frames deeper than 1 cm, person 2 against person 1."""
    from umf.data.relations import pair_closeness
    from umf.eval.physics import interpenetration

    pen = interpenetration(joints[:2])[1]
    return {**pair_closeness(joints), "penetration_cm": round(pen["penetration_cm"], 3),
            "penetration_frac": round(pen["penetration_frac"], 3)}  # fmt: skip


def salsa_pass(c: dict) -> bool:
    return c["hands_near"] >= 0.5 and 0.25 <= c["pelvis"] <= 1.0 and c["facing"] > 0.5


CLIPS = {
    "backflip": "backflip",
    "cartwheel": "cartwheel",
    "crawl": "crawl",
    "jump": "jump",
    "getup_facedown": "getup",
    "getup_faceup": "getup",
}  # DeepMimic clip -> its check


def reconstructed(pipe, corpus) -> list[dict]:
    """The action checks on the VAE's reconstruction of each DeepMimic clip's first 4 s
    (canonical frame), beside the real clip's value, and the pose error (root-relative,
    mean over joints and frames): whether the VAE can hold the action at all."""
    import torch

    from umf.eval.reconstruction import reconstruct
    from umf.representation import canonicalize_scene, joints_to_features

    rows = []
    for c in corpus.clips:
        name = c.id.rsplit("humanoid3d_", 1)[-1]
        if "deepmimic" not in c.id or "sie" in c.id or name not in CLIPS:
            continue
        canon, _ = canonicalize_scene(torch.from_numpy(c.joints[0][: 4 * 30 + 1][None]).float())
        feats = joints_to_features(canon[0]).numpy()
        rec = reconstruct(pipe.vae, pipe.normalizer, [feats])[0]
        real, back = feats[:, :66].reshape(-1, 22, 3), rec[:, :66].reshape(-1, 22, 3)
        _, v_real = action_check(CLIPS[name], real)
        ok, v = action_check(CLIPS[name], back)
        err = np.linalg.norm((back - back[:, :1]) - (real - real[:, :1]), axis=-1).mean()
        rows.append({"clip": name, "kind": CLIPS[name], "real": round(v_real, 3),
                     "vae": round(v, 3), "pass": ok,
                     "pose_error_m": round(float(err), 3)})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None, help="for the real takes beside")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    report: dict = {"model": pipe.name, "seeds": args.seeds, "salsa": {}, "actions": {}}
    seeds = range(args.seeds)
    for view in ("delivered", "raw"):
        report["salsa"][view] = []
    for s in seeds:
        (scene,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
        for view, j in (("delivered", scene.joints), ("raw", scene.raw_joints)):
            c = closeness(np.asarray(j))
            report["salsa"][view].append({**c, "pass": salsa_pass(c)})
        report.setdefault("salsa_coverage", scene.meta.get("coverage"))
    if args.corpus is not None:
        from umf.data.corpus import Corpus

        corpus = Corpus.load(args.corpus)
        report["salsa"]["real"] = []
        for c in corpus.clips:
            if c.meta.get("content") == "salsa" and c.split in ("test", "val"):
                t = c.joints[:, : 4 * 30 + 1]  # the first 4 s, as generated
                m = closeness(c.joints)
                report["salsa"]["real"].append({"id": c.id, "split": c.split, **m,
                                                "first_4s": closeness(t),
                                                "pass": salsa_pass(m)})  # fmt: skip
    runs = [(kind, kind, prompt, 4.0) for kind, prompt in ACTIONS.items()]
    runs.append(("getup_3s", "getup", ACTIONS["getup"], 3.0))  # the real clip's own length
    for key, kind, prompt, seconds in runs:
        rows = []
        for s in seeds:
            (scene,) = pipe(prompt, num_people=1, seconds=seconds, seed=s)
            ok, v = action_check(kind, np.asarray(scene.joints[0]))
            ok_raw, v_raw = action_check(kind, np.asarray(scene.raw_joints[0]))
            end_head = float(scene.joints[0, -10:, 15, 1].mean())
            rows.append({"seed": s, "pass": ok, "value": round(v, 3), "raw_pass": ok_raw,
                         "raw_value": round(v_raw, 3), "end_head": round(end_head, 3)})  # fmt: skip
        report["actions"][key] = {"prompt": prompt, "seconds": seconds, "seeds": rows,
                                   "passed": sum(r["pass"] for r in rows),
                                   "raw_passed": sum(r["raw_pass"] for r in rows)}  # fmt: skip

    if args.corpus is not None:  # what the VAE alone makes of the real clips (first 4 s)
        report["reconstructed"] = reconstructed(pipe, corpus)

    def med(rows, k):
        return float(np.median([r[k] for r in rows]))

    print(f"model {pipe.name}; {args.seeds} seeds, 4 s")
    print("salsa (medians)  hands_near  pelvis/stature  facing  min joint (m)  overlap (cm, "
          "frames > 1 cm)  passed")  # fmt: skip
    for view, rows in report["salsa"].items():
        print(f"  {view:14s} {med(rows, 'hands_near'):10.2f} {med(rows, 'pelvis'):15.2f} "
              f"{med(rows, 'facing'):7.2f} {med(rows, 'min_joint_m'):14.3f}  "
              f"{med(rows, 'penetration_cm'):6.2f}, {med(rows, 'penetration_frac'):.2f}"
              f"{'':14s}{sum(r['pass'] for r in rows)}/{len(rows)}")  # fmt: skip
    for kind, r in report["actions"].items():
        vals = ", ".join(f"{x['value']:.2f}" for x in r["seeds"])
        if kind.startswith("getup"):
            vals += "; head over the last 10 frames " + ", ".join(
                f"{x['end_head']:.2f}" for x in r["seeds"]
            )
        print(f"{kind:10s} delivered {r['passed']}/{args.seeds}, raw {r['raw_passed']}/{args.seeds}"
              f"  ({vals})")  # fmt: skip
    for row in report.get("reconstructed", []):
        print(f"reconstructed {row['clip']:28s} {row['kind']:9s} real {row['real']:6.2f} "
              f"VAE {row['vae']:6.2f} ({'pass' if row['pass'] else 'fail'}), pose error "
              f"{row['pose_error_m'] * 100:.0f} cm")  # fmt: skip
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
