"""The first trial of the retrieved warm start, before umf.reaction_bank: `umf eval` run
with people 2..N warm-started from one of the K nearest reactions of CORPUS's train split,
the bank built lazily at each generated length (the model given must set
sflow.warm_start; its warm_proposal is replaced here).

    python lazy_bank_eval.py CORPUS K eval --checkpoint MODEL --corpus CORPUS --quick ...
"""

import sys

import torch

import umf.pipeline
from umf.cli.main import app
from umf.data.corpus import Corpus
from umf.train.datasets import SceneDataset

corpus = Corpus.load(sys.argv[1])
k = int(sys.argv[2])
banks: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}


def build_at(pipe, frames):
    ds = SceneDataset(corpus, "train", corpus.normalizer, min_frames=frames, max_frames=frames,
                      mirror=True, seed=0)  # fmt: skip
    people = [p for i in range(len(ds)) for p in ds[i]["features"][1:]
              if p.shape[0] == frames]  # fmt: skip
    x = torch.stack(people)  # raises on an empty list: the caller tries a shorter length
    m = torch.ones(x.shape[:2], dtype=torch.bool)
    with torch.no_grad():
        b = torch.cat([pipe.vae.encode(x[i : i + 256], m[i : i + 256])[0]
                       for i in range(0, len(x), 256)])  # fmt: skip
    return b, pipe.sflow.latent_norm.normalize(b).flatten(1)


def bank_for(pipe, frames):
    if frames not in banks:
        for length in range(frames, 14, -15):
            try:
                banks[frames] = build_at(pipe, length)
                break
            except RuntimeError:
                continue
    return banks[frames]


def retrieve(pipe, first, text, uncond, frames, gen, guidance, own):
    bank, normalized = bank_for(pipe, frames)
    q = pipe.sflow.latent_norm.normalize(first).flatten(1)
    idx = torch.cdist(q, normalized).topk(k, largest=False).indices
    pick = torch.randint(0, k, (q.shape[0],))
    return bank[idx[torch.arange(q.shape[0]), pick]], 0


umf.pipeline.proposal = retrieve
torch.manual_seed(0)
sys.argv = ["umf", *sys.argv[3:]]
app()
