"""A loss on the decoded reaction's feet (``train_sflow.foot_loss``): where the real
reaction's feet are planted, the reaction the S-Flow points at may not slide them faster.

Why: the S-Flow's walking followers glide, their feet carried along at 0.76 m/s against the
leader's 0.14 (results/umf-small-bandai-20261204), and the clean-up then delivers what the
legs do: 0.7x the leader's pace. In latent MSE a glide and a stride along the same path cost
alike, so the flow's own loss cannot tell them apart; the frozen decoder can.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from umf.models.vae import foot_contact_loss
from umf.representation import Normalizer, features_to_joints, foot_contacts, fuse_positions

FOOT_ROWS = 32  # rows of a batch decoded for the loss: the decoder's cost stays bounded
FOOT_FRAMES = 150  # frames each is decoded to at most (5 s at 30 fps)


def decoded_joints(
    vae: nn.Module,
    normalizer: Normalizer,
    z: Tensor,
    frames: int,
    fusion: tuple[float, float, float | None] | None = None,
) -> Tensor:
    """Joints (B, frames, 22, 3) in metres of latents ``z`` (B, p, r) through the decoder, fused
    with ``fusion`` (:func:`umf.representation.fuse_positions`'s weights) where given: how the
    losses on decoded reactions read a latent."""
    mask = torch.ones(z.shape[0], frames, dtype=torch.bool, device=z.device)
    features = normalizer.denormalize(vae.decode(z, mask)).float()
    if fusion is not None:
        features = fuse_positions(features, *fusion)
    return features_to_joints(features)


def decoded_foot_slide(
    vae: nn.Module,
    normalizer: Normalizer,
    w: Tensor,
    w_hat: Tensor,
    t: Tensor,
    min_t: float = 0.5,
    rows: int = FOOT_ROWS,
    frames: int = FOOT_FRAMES,
    fusion: tuple[float, float, float | None] | None = None,
) -> Tensor:
    """Mean excess speed (m/frame) of ``w_hat``'s decoded feet over ``w``'s where ``w``'s
    decoded feet are planted (:func:`umf.models.vae.foot_contact_loss`).

    ``w`` / ``w_hat`` (B, p, r): the real reactions and the ones the flow points at, in
    latent units; ``t`` (B,): their flow times. Only rows at ``t >= min_t`` count (up to
    ``rows`` of them): early on the flow points at a blur of every reaction the context
    allows, whose feet slide whatever the flow does. Both are decoded to ``frames`` frames,
    so the real reaction's contacts and the estimate's are read alike, and with
    ``fusion`` (:func:`umf.representation.fuse_positions`'s weights) fused as the pipeline
    delivers them: the raw decoded positions jitter by centimetres a frame, the size of the
    contact rule's threshold. Gradients reach ``w_hat`` only (the decoder is frozen by its
    caller). Zero when no row qualifies.
    """
    keep = torch.nonzero(t >= min_t).squeeze(1)[:rows]
    if keep.numel() == 0:
        return w_hat.sum() * 0.0
    mask = torch.ones(keep.numel(), frames, dtype=torch.bool, device=w.device)
    with torch.no_grad():
        ref = decoded_joints(vae, normalizer, w[keep], frames, fusion)
        planted = F.pad(foot_contacts(ref), (0, 0, 0, 1))  # (B, T, 4): a pair per frame
    moved = decoded_joints(vae, normalizer, w_hat[keep], frames, fusion)
    return foot_contact_loss(moved, ref, planted, mask)
