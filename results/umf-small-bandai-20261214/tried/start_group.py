"""Throw-away: people k >= 3 (a context of 2+ people) sample their second pass from UMF_T3."""

import os
import runpy
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "research"))
import umf.models.sflow as sf

T3 = float(os.environ["UMF_T3"])
orig = sf.SFlow.sample


def sample(self, prev, mask, *a, warm=None, warm_t=None, **kw):
    if warm is not None and warm_t is None and prev.shape[1] > 1:
        warm_t = T3
    return orig(self, prev, mask, *a, warm=warm, warm_t=warm_t, **kw)


sf.SFlow.sample = sample
script = sys.argv[1]
sys.argv = sys.argv[1:]
runpy.run_path(script, run_name="__main__")
