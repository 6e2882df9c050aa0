"""bow_back timing: warm start from the real reaction whose leader best matches person 1."""

import os
import sys
from pathlib import Path

import numpy as np
import torch

import umf.pipeline as PL
from umf.data.corpus import Corpus
from umf.data.relations import action_onset
from umf.flows.noise import randn
from umf.pipeline import UMFPipeline
from umf.train.datasets import SceneDataset

mode, t0, k, relation, prompt = (
    sys.argv[1],
    float(sys.argv[2]),
    int(sys.argv[3]),
    sys.argv[4],
    sys.argv[5],
)
pipe = UMFPipeline.from_pretrained(None)
if mode != "base":
    corpus = Corpus.load(os.environ.get("CORPUS", str(Path.home() / "umf-runs/full/corpus")))
    ds = SceneDataset(
        corpus,
        "train",
        pipe.normalizer,
        min_frames=120,
        max_frames=120,
        mirror=True,
        seed=0,
        real_clips=False,
    )
    ds.items = [it for it in ds.items if it[1].get("relation") == relation]
    lead, fol = [], []
    for i in range(len(ds)):
        f = ds[i]["features"]
        if f.shape[1] == 120:
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
        LEAD, FOL = enc(torch.stack(lead)), enc(torch.stack(fol))
    print("bank", len(lead), flush=True)

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
        norm = pipe_.sflow.latent_norm.normalize
        q = (
            prev[:, 0]
            if mode == "leader"
            else pipe_.sflow.sample(prev, mask, text, uncond, **kw)[0]
        )
        bank = LEAD if mode == "leader" else FOL
        d = torch.cdist(norm(q).flatten(1), norm(bank).flatten(1))
        idx = d.topk(k, dim=1, largest=False).indices
        pick = randn((prev.shape[0], k), generator).argmax(dim=1)
        guess = FOL[idx[torch.arange(prev.shape[0]), pick]]
        pipe_.sflow.cfg.warm_start = t0
        return pipe_.sflow.sample(prev, mask, text, uncond, warm=guess, **kw)

    PL.sample_added = sample_added
lags = []
for s in range(16):
    (scene,) = pipe(prompt, num_people=2, seconds=4.0, seed=s)
    j = np.asarray(scene.joints)
    lags.append(action_onset(j[1]) - action_onset(j[0]))
print(mode, t0, k, "lags", lags, "starts_after>=8:", sum(l >= 8 for l in lags), "/ 16")
