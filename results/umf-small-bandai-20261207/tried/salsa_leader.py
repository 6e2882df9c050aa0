"""Salsa: warm start from the real follower whose leader best matches person 1 (experiment)."""

import os
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))
from teach_report import SALSA, closeness, salsa_pass

import umf.warm_start as W
from umf.data.corpus import Corpus
from umf.flows.noise import randn
from umf.pipeline import UMFPipeline
from umf.train.datasets import SceneDataset

t0 = float(sys.argv[1])
k = int(sys.argv[2])
repeats = int(sys.argv[3])
pipe = UMFPipeline.from_pretrained(None)
corpus = Corpus.load(os.environ.get("CORPUS", str(Path.home() / "umf-runs/full/corpus")))
bank = {}
for frames in [120]:
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
    ds.items = [
        it for it in ds.items if it[0] == "clip" and "salsa" in " ".join(it[1].captions).lower()
    ]
    lead, fol = [], []
    for i in range(len(ds)):
        f = ds[i]["features"]
        if f.shape[1] == frames:
            lead.append(f[0])
            fol.append(f[1])

    def enc(x):
        return torch.cat(
            [
                pipe.vae.encode(
                    x[j : j + 256], torch.ones(x[j : j + 256].shape[:2], dtype=torch.bool)
                )[0]
                for j in range(0, len(x), 256)
            ]
        )

    with torch.no_grad():
        bank[frames] = (enc(torch.stack(lead)), enc(torch.stack(fol)))
    print(frames, len(lead), flush=True)
STATE = {}
orig_sample_added = W.sample_added


def sample_added(
    pipe_,
    prev,
    mask,
    text,
    uncond,
    frames,
    *,
    steps,
    guidance,
    generator,
    own,
    pflow_guidance,
    mirror=None,
):
    kw = {"steps": steps, "guidance": guidance, "generator": generator, **own}
    lead, fol = bank[120]
    norm = pipe_.sflow.latent_norm.normalize
    d = torch.cdist(norm(prev[:, 0]).flatten(1), norm(lead).flatten(1))
    idx = d.topk(k, dim=1, largest=False).indices
    pick = randn((prev.shape[0], k), generator).argmax(dim=1)
    guess = fol[idx[torch.arange(prev.shape[0]), pick]]
    if t0 >= 1.0:
        return guess, 0
    pipe_.sflow.cfg.warm_start = t0
    w, n = pipe_.sflow.sample(prev, mask, text, uncond, warm=guess, **kw)
    return w, n


W.sample_added = sample_added
import umf.pipeline as PL  # noqa: E402

PL.sample_added = sample_added
rows = []
for s in range(8):
    (scene,) = pipe(SALSA, num_people=2, seconds=4.0, seed=s)
    c = closeness(np.asarray(scene.joints))
    rows.append(c)
    print(
        s,
        {
            kk: round(v, 3) if isinstance(v, float) else v
            for kk, v in c.items()
            if kk in ("hands_near", "pelvis", "facing", "penetration_cm")
        },
        salsa_pass(c),
        flush=True,
    )
for kk in ("hands_near", "pelvis", "facing"):
    print(kk, "median", round(float(np.median([r[kk] for r in rows])), 3))
print("passing", sum(salsa_pass(r) for r in rows), "/ 8")
