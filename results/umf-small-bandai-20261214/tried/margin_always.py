"""Throw-away: group_checks / keep_pace with the caption shortlist narrowed to captions within
DELTA of the best one (env UMF_DELTA)."""

import os
import runpy
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))
import torch

import umf.reaction_bank as rb

DELTA = float(os.environ["UMF_DELTA"])
orig = rb.ReactionBank._shortlisted


def _shortlisted(self, length, prompt, shortlist, like, mirror=None):
    out = orig(self, length, prompt, shortlist, like, mirror)
    if out is None:
        return out
    sims = prompt.to(like) @ self.texts[length].to(like).T
    best = sims.masked_fill(~out, -torch.inf).max(dim=1, keepdim=True).values
    return out & (sims >= best - DELTA)


rb.ReactionBank._shortlisted = _shortlisted
script = sys.argv[1]
sys.argv = sys.argv[1:]
runpy.run_path(script, run_name="__main__")
