"""Weights a fine-tune adds to the model it starts from (``umf train finetune``, ``--init``):
which keys may be missing from the released weights, which start as built, and how the log
names them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

# Weights a fine-tune may add to the model it starts from: new ones start as built. A new
# own-prompt head (``denoiser.person_head``) also restarts the projection after it, which
# was trained on the scene head's output: the fine-tune starts as the model it came from.
PROJECTION = ("person_proj.weight", "person_proj.bias")
# The S-Flow's context beside its state (``sflow.context_condition``) starts at zero too.
GROWN = ("detail_gain", *PROJECTION, "cond_proj.weight", "cond_proj.bias")


def _in_person_head(key: str) -> bool:
    return key.startswith("person_head.") or ".person_head." in key


def grows(key: str) -> bool:
    """Whether a fine-tune may add weight ``key`` to a model that lacks it."""
    return key.endswith(GROWN) or _in_person_head(key)


def grown_names(keys: Sequence[str]) -> list[str]:
    """The grown weights for the log: a new head's tensors as one ``net.person_head.*``."""
    heads = [k for k in keys if _in_person_head(k)]
    names = sorted(k for k in keys if k not in heads)
    if heads:
        where = heads[0][: heads[0].index("person_head.")]
        names.append(f"{where}person_head.* ({len(heads)} tensors)")
    return names


def grown_keys(own: Mapping[str, Any], loaded: Mapping[str, Any]) -> list[str]:
    """The keys of ``own`` (the module as built) a fine-tune takes as built rather than from
    the ``loaded`` weights: the ones the model lacks and, beside a new own-prompt head, the
    projection after it (trained on the scene head's output, it would read the new head's
    as noise; restarted at zero, the own prompt starts with no effect)."""
    grown = [k for k in own if grows(k) and k not in loaded]
    if any(_in_person_head(k) for k in grown):
        grown += [k for k in own if k.endswith(PROJECTION) and k not in grown]
    return grown
