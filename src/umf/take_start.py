"""A couple started from a real take: people 1 and 2 of a prompt worded like a touching take.

The bundled model's two-person scenes are two solo clips composed apart, except for a few
real takes (CMU's salsa couples, a handshake). Asked for a salsa couple, the P-Flow's
leader and the S-Flow's partner each dance, but their hands do not find each other: the
median seed held hands in 12 % of its frames, where the real takes do in 60-80 %
(results/umf-small-bandai-20261213). With ``sflow.warm_take`` a scene whose prompt the
model's vocabulary reads as worded like such a take (its coverage's ``contact``,
:mod:`umf.coverage`) draws one crop of those takes from the model's bank (both people,
:meth:`umf.reaction_bank.ReactionBank.pick_take`), with the scene's own generator, and

- person 1 is sampled again by the P-Flow from ``warm_take`` on its finest stage's path
  towards the crop's person 1 (:func:`umf.flows.pyramid.sample_finest_from`);
- person 2 by the S-Flow from ``warm_take`` on its path towards the crop's person 2, beside
  the new person 1 (:func:`umf.flows.warm_state`).

Both flows finish the motion from a noisy real couple, so the scene is a variation of a
training take, not the take itself; how far it strays is ``warm_take`` (1: the take
decoded; the bundled model's 0.7 was chosen on the salsa seeds, results/...). A model whose
bank has no takes, a scene with an actor (person 1 is the user's motion) or with own
prompts per person keeps the flows' own pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import torch

Tensor = torch.Tensor


class Couples(NamedTuple):
    """The rows of a batch started from a take, both people's latents of each row's crop
    (R, 2, p, r) on the VAE's scale, and where each crop was cut
    (:meth:`umf.reaction_bank.ReactionBank.take_source`; None for an older bank)."""

    rows: Tensor
    pair: Tensor
    sources: list[dict[str, Any] | None]


def couple_rows(
    pipe: Any, text: Any, contact: Sequence[dict | None], frames: int, generator: Any
) -> Couples | None:
    """The rows of a batch whose prompt is worded like a touching take, and for each a crop
    of those takes (:class:`Couples`), drawn with the row's generator (a list, one per
    row). A row whose take is too short for ``frames`` has none. None where no row has
    one, the model sets no ``sflow.warm_take`` or its bank holds no takes."""
    bank = pipe.reactions
    if not pipe.config.sflow.warm_take or bank is None or not bank.takes:
        return None
    rows = torch.tensor([i for i, c in enumerate(contact) if c], dtype=torch.long)
    if not len(rows):
        return None
    prompt = torch.nn.functional.normalize(text.pooled[rows].float(), dim=-1)
    length, idx, own = bank.pick_take(frames, prompt, [generator[i] for i in rows.tolist()])
    own = own.cpu()
    if not bool(own.any()):
        return None
    idx = idx.cpu()[own]
    return Couples(
        rows[own], bank.takes[length][idx].to(pipe.device), bank.take_source(length, idx)
    )


def start_couples(
    pipe: Any, z1: Tensor, text: Any, uncond: Any, generator: Any,
    contact: Sequence[dict | None] | None, frames: int, pflow: dict[str, Any],
) -> tuple[Tensor, Couples | None, int]:  # fmt: skip
    """Person 1's latents (B, p, r) with the rows worded like a touching take started from
    one of its crops (:func:`couple_rows`, :func:`start_leaders`), those rows and crops (for
    :func:`start_partners`; None: no row) and the NFE. ``contact``: per row, the prompt's
    coverage contact (None: no row touches)."""
    couples = couple_rows(pipe, text, contact or [None] * len(z1), frames, generator)
    if couples is None:
        return z1, None, 0
    z1, nfe = start_leaders(pipe, z1, couples, text, uncond, generator, **pflow)
    return z1, couples, nfe


def start_leaders(
    pipe: Any, z1: Tensor, couples: Couples, text: Any, uncond: Any,
    generator: Any, **pflow: Any,
) -> tuple[Tensor, int]:  # fmt: skip
    """Person 1's latents (B, p, r) with the couples' rows sampled again by the P-Flow from
    ``sflow.warm_take`` towards their take's person 1, and the NFE. ``pflow``: the
    pipeline's P-Flow arguments (dataset token, steps, guidance)."""
    rows, pair, _ = couples
    again, nfe = pipe.pflow.sample(
        text.rows(rows), _rows(uncond, rows), generator=[generator[i] for i in rows.tolist()],
        warm=pair[:, 0], warm_t=pipe.config.sflow.warm_take,
        **{k: v[rows] if k == "dataset" else v for k, v in pflow.items()},
    )  # fmt: skip
    z1 = z1.clone()
    z1[rows] = again.to(z1)
    return z1, nfe


def start_partners(
    pipe: Any, w: Tensor, couples: Couples, prev: Tensor, mask: Tensor,
    text: Any, uncond: Any, generator: Any, *, steps: int, guidance: float | None,
) -> tuple[Tensor, int]:  # fmt: skip
    """Person 2's latents (B, p, r) with the couples' rows sampled again by the S-Flow from
    ``sflow.warm_take`` towards their take's person 2, beside person 1 (``prev`` (B, 1, p,
    r)), and the NFE."""
    rows, pair, _ = couples
    again, nfe = pipe.sflow.sample(
        prev[rows], mask[rows], text.rows(rows), _rows(uncond, rows), steps=steps,
        guidance=guidance, generator=[generator[i] for i in rows.tolist()], warm=pair[:, 1],
        warm_t=pipe.config.sflow.warm_take,
    )  # fmt: skip
    w = w.clone()
    w[rows] = again.to(w)
    return w, nfe


def _rows(uncond: Any, rows: Tensor) -> Any:
    """The empty prompt's features for ``rows``: one row serves them all."""
    return uncond if uncond.tokens.shape[0] == 1 else uncond.rows(rows)
