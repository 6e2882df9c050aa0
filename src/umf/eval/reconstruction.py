"""How well the motion VAE reconstructs real motion, per feature group.

A VAE that only learns where a person is and outputs the mean pose can still score a
low MPJPE (the root error dominates it). So reconstructions are judged group by group
against the simplest baseline, the per-dimension mean over the clips scored: R^2 = 1 -
SSE / SST is 1 for a perfect reconstruction, 0 for the mean pose and negative for
something worse. Groups are those of the body frame (:mod:`umf.body_frame`): the pelvis
path, the heading, and the pose (positions, velocities) in the body's own heading frame,
so a turned but otherwise right pose is a heading error, not a pose error.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from umf.body_frame import (
    BODY_CONTACT,
    BODY_ROT,
    HEADING,
    LOCAL_POS,
    LOCAL_VEL,
    ROOT,
    to_body_frame,
)
from umf.representation import POS, Normalizer, fuse_positions

Array = np.ndarray


@torch.no_grad()
def reconstruct(
    vae: torch.nn.Module,
    normalizer: Normalizer,
    features: Sequence[Array],
    batch_size: int = 64,
    root_fusion: float | None = None,
) -> list[Array]:
    """Encode (posterior mean) and decode raw features (T_i, 262) -> raw features, same T_i.

    Decoded as the pipeline decodes (positions fused with velocities); ``root_fusion``
    overrides the VAE's weight of the pelvis path (None: the VAE's own)."""
    vae.eval()
    device = next(vae.parameters()).device
    out: list[Array] = []
    for i in range(0, len(features), batch_size):
        chunk = [torch.as_tensor(np.asarray(f), dtype=torch.float32) for f in
                 features[i : i + batch_size]]  # fmt: skip
        t = max(f.shape[0] for f in chunk)
        x = torch.zeros(len(chunk), t, chunk[0].shape[-1])
        mask = torch.zeros(len(chunk), t, dtype=torch.bool)
        for j, f in enumerate(chunk):
            x[j, : f.shape[0]], mask[j, : f.shape[0]] = f, True
        x = normalizer.normalize(x).masked_fill(~mask[..., None], 0.0).to(device)
        mask = mask.to(device)
        mu, _ = vae.encode(x, mask)
        y = normalizer.denormalize(vae.decode(mu, mask))
        # as the pipeline decodes: positions made consistent with velocities, per clip
        position, root, height = vae.cfg.fusion_weights()
        root = root if root_fusion is None else root_fusion
        y = [fuse_positions(y[j, : f.shape[0]], position, root, height)
             for j, f in enumerate(chunk)]  # fmt: skip
        out.extend(r.cpu().numpy() for r in y)
    return out


def feature_groups(features: Array) -> dict[str, Array]:
    """Raw features (T, 262) -> the groups scored, (T, d) arrays: the body-frame groups
    (:mod:`umf.body_frame`), so that the pose is judged apart from where the body faces."""
    body = to_body_frame(torch.as_tensor(features, dtype=torch.float64)).numpy()
    return {
        "trajectory": body[:, ROOT],
        "heading": body[:, HEADING],
        "positions": body[:, LOCAL_POS][:, 3:],  # the pelvis's x, z are 0 by construction
        "velocities": body[:, LOCAL_VEL],
        "rotations": body[:, BODY_ROT],
        "contacts": body[:, BODY_CONTACT],
    }


def r_squared(pred: Array, true: Array) -> float:
    """1 - SSE / SST over all dimensions, SST about the per-dimension mean of ``true``."""
    sse = float(((pred - true) ** 2).sum())
    sst = float(((true - true.mean(0)) ** 2).sum())
    return 1.0 - sse / max(sst, 1e-12)


def reconstruction_metrics(real: Sequence[Array], recon: Sequence[Array]) -> dict[str, float]:
    """MPJPE (global and root-relative, m), per-joint errors of the extremities, and R^2 of
    every group, over all frames of aligned raw feature lists (T_i, 262)."""
    r, p = np.concatenate(list(real)), np.concatenate(list(recon))
    rj, pj = r[:, POS].reshape(-1, 22, 3), p[:, POS].reshape(-1, 22, 3)
    rel_r, rel_p = rj - rj[:, :1], pj - pj[:, :1]
    out = {
        "mpjpe_m": float(np.linalg.norm(pj - rj, axis=-1).mean()),
        "mpjpe_root_relative_m": float(np.linalg.norm(rel_p - rel_r, axis=-1).mean()),
        "wrist_error_m": float(np.linalg.norm(rel_p - rel_r, axis=-1)[:, [20, 21]].mean()),
    }
    gr, gp = feature_groups(r), feature_groups(p)
    out |= {f"r2_{k}": r_squared(gp[k], gr[k]) for k in gr}
    return out
