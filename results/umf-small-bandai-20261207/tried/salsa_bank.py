"""Salsa with a warm start from real takes' reactions (experiment)."""

import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))
from teach_report import SALSA, closeness, salsa_pass

from umf.coverage import embed
from umf.data.corpus import Corpus
from umf.pipeline import UMFPipeline
from umf.reaction_bank import ReactionBank
from umf.train.datasets import SceneDataset
from umf.warm_start import floor_velocity

mode = sys.argv[1]  # base | realbank
repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 40
pipe = UMFPipeline.from_pretrained(None)
if mode != "base":
    corpus = Corpus.load(os.environ.get("CORPUS", str(Path.home() / "umf-runs/full/corpus")))
    lat, tx, vel = {}, {}, {}
    t = time.time()
    for frames in [105, 120, 135]:
        ds = SceneDataset(
            corpus,
            "train",
            pipe.normalizer,
            min_frames=frames,
            max_frames=frames,
            mirror=True,
            seed=0,
            real_repeats=repeats,
        )
        ds.items = [it for it in ds.items if it[0] == "clip"]
        people, caps = [], []
        for i in range(len(ds)):
            it = ds[i]
            f = it["features"]
            if f.shape[1] == frames:
                people.extend(f[1:])
                caps.extend([it["caption"]] * (f.shape[0] - 1))
        x = torch.stack(people)
        mask = torch.ones(x.shape[:2], dtype=torch.bool)
        distinct = sorted(set(caps))
        row = {c: i for i, c in enumerate(distinct)}
        tx[frames] = embed(pipe.text_encoder, distinct)[[row[c] for c in caps]]
        vel[frames] = floor_velocity(pipe.normalizer.denormalize(x), pipe.config.fps)
        with torch.no_grad():
            lat[frames] = torch.cat(
                [
                    pipe.vae.encode(x[j : j + 256], mask[j : j + 256])[0]
                    for j in range(0, len(x), 256)
                ]
            )
        print(frames, len(x), distinct, time.time() - t, flush=True)
    pipe.reactions = ReactionBank(lat, tx, vel)
    cfg = pipe.config.sflow
    cfg.warm_glide = 0.0
    cfg.warm_pace = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
    if len(sys.argv) > 4:
        cfg.warm_start = float(sys.argv[4])
rows = []
for s in range(8):
    (scene,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
    c = closeness(np.asarray(scene.joints))
    rows.append(c)
    print(
        s,
        {k: round(v, 3) if isinstance(v, float) else v for k, v in c.items()},
        salsa_pass(c),
        flush=True,
    )
for k in ("hands_near", "pelvis", "facing"):
    print(k, "median", round(float(np.median([r[k] for r in rows])), 3))
print("passing", sum(salsa_pass(r) for r in rows), "/ 8")
