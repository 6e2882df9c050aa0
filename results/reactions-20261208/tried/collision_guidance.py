"""Tried, not kept: people 2..N steered off everybody before them inside the S-Flow's ODE.

    ETA=0.03 MARGIN=0.35 ITERS=1 python results/reactions-20261208/tried/collision_guidance.py \
        --corpus CORPUS --scenes 100     # then any research/group_checks.py option

At every Euler step the reaction the velocity points at (x + (1 - t) v) is decoded, its joints
closer than MARGIN to an earlier person's are penalised (squared), and the endpoint moves
ETA down that penalty's gradient (ITERS times); the step then heads for the moved endpoint.
Reconstruction guidance through the VAE's decoder, wrapped around ``umf.pipeline.sample_added``
and ``umf.models.sflow.sample_semi_noise`` for this run only.
"""

import os
import runpy
import sys

import torch

import umf.models.sflow as sflow_module
import umf.pipeline as pipeline
from umf.representation import features_to_joints

ETA = float(os.environ.get("ETA", "1.0"))
MARGIN = float(os.environ.get("MARGIN", "0.35"))
ITERS = int(os.environ.get("ITERS", "1"))
STATE: dict = {}
sample_added = pipeline.sample_added
sample_semi_noise = sflow_module.sample_semi_noise


def added(pipe, prev, mask, text, uncond, frames, **kw):
    """Decode everybody before the new person once, for the penalty."""
    with torch.no_grad():
        others = [features_to_joints(pipe.decode(prev[:, j], frames, reaction=j > 0))
                  for j in range(prev.shape[1])]  # fmt: skip
    STATE.update(pipe=pipe, frames=frames, others=torch.stack(others, 1))
    try:
        return sample_added(pipe, prev, mask, text, uncond, frames, **kw)
    finally:
        STATE.clear()


def penalty(joints, others):
    """(B,) squared shortfall below MARGIN of every joint pair, the new person's (B, T, 22, 3)
    against the earlier people's (B, n, T, 22, 3), summed."""
    mine = joints[:, None].expand_as(others).reshape(-1, 22, 3)
    d = torch.cdist(mine, others.reshape(-1, 22, 3))
    return torch.relu(MARGIN - d).pow(2).reshape(others.shape[0], -1).sum(1)


def guided_sampler(field, context, **kw):
    if not STATE:
        return sample_semi_noise(field, context, **kw)
    pipe, frames, others = STATE["pipe"], STATE["frames"], STATE["others"]
    norm = pipe.sflow.latent_norm

    def guided(x, t, **cond):
        v = field(x, t, **cond)
        r = x.shape[-1] // 2
        xr, vr = x[..., r:], v[..., r:]
        now = float(t[0])
        e = (xr + (1 - now) * vr).detach()
        for _ in range(ITERS):
            with torch.enable_grad():
                e = e.requires_grad_(True)
                j = features_to_joints(pipe.decode(norm.denormalize(e), frames, reaction=True))
                (g,) = torch.autograd.grad(penalty(j, others).sum(), e)
            e = (e - ETA * g).detach()
        return torch.cat([v[..., :r], (e - xr) / max(1 - now, 1e-3)], -1)

    return sample_semi_noise(guided, context, **kw)


sflow_module.sample_semi_noise = guided_sampler
pipeline.sample_added = added
sys.argv[0] = "research/group_checks.py"
runpy.run_path("research/group_checks.py", run_name="__main__")
