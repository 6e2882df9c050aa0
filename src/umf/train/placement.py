"""A loss on where the decoded reaction stands (``train_sflow.place_loss``): the pelvis's floor
path of the reaction the S-Flow points at, against the real reaction's, in metres.

Why: the S-Flow's text token cannot tell "the second person on the first one's left" from
"... right" (centred cosine 0.998, ``research/scene_tokens.py``), so it puts a named side's
partner in the middle, on person 1 (results/reactions-20261208). From a late flow time the
state itself says where the reaction stands; only early, where it does not, does the prompt
have to. There the latent MSE weighs a wrong side little; the decoded floor path weighs it in
metres.

``train_sflow.joint_loss`` reads the same decoding for every joint in 3-D: where the hands
are (a salsa couple holding them) and when the body bends (a bow back after a bow), which the
pelvis's floor path does not say.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from umf.representation import Normalizer
from umf.train.foot_slide import FOOT_ROWS, decoded_joints


def decoded_place_errors(
    vae: nn.Module,
    normalizer: Normalizer,
    w: Tensor,
    w_hat: Tensor,
    t: Tensor,
    max_t: float = 0.5,
    rows: int = FOOT_ROWS,
    frames: int = 30,
    fusion: tuple[float, float, float | None] | None = None,
) -> dict[str, Tensor]:
    """Where ``w_hat``'s decoding stands against ``w``'s, in metres, over ``frames`` frames and
    the rows at flow time ``t <= max_t`` (up to ``rows``), from one decoding of each:

    - ``place``: the pelvis's mean floor (x, z) distance;
    - ``joint``: every joint's mean 3-D distance, in person 1's frame (so a hand held at the
      wrong height or a bow a second late counts, as well as a partner in the wrong place).

    ``w`` / ``w_hat`` (B, p, r): the real reactions and the ones the flow points at, in
    latent units; both decoded alike (``fusion``: :func:`umf.representation.fuse_positions`'s
    weights, as the pipeline decodes people 2..N). Gradients reach ``w_hat`` only (the
    decoder is frozen by its caller). Zeros when no row qualifies.
    """
    keep = torch.nonzero(t <= max_t).squeeze(1)[:rows]
    if keep.numel() == 0:
        zero = w_hat.sum() * 0.0
        return {"place": zero, "joint": zero}
    with torch.no_grad():
        ref = decoded_joints(vae, normalizer, w[keep], frames, fusion)
    moved = decoded_joints(vae, normalizer, w_hat[keep], frames, fusion)
    return {
        "place": (moved[:, :, 0][..., [0, 2]] - ref[:, :, 0][..., [0, 2]]).norm(dim=-1).mean(),
        "joint": (moved - ref).norm(dim=-1).mean(),
    }
