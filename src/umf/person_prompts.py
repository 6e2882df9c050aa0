"""Per-person prompts at sampling time: whether a model takes them, each person's own prompt
as a flow's sampler takes it, and what a scene records of them (prompts and coverage)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from umf.errors import UMFError
from umf.text import respell_prompt


def takes_person_prompts(config: Any) -> bool:
    """Whether a model of this config takes a prompt per person (both flows built with
    ``denoiser.person_text``): read from the config, so it is known before loading."""
    return bool(config.pflow.denoiser.person_text and config.sflow.denoiser.person_text)


def check_person_prompts(
    config: Any, own: Sequence[str | None], acting: bool = False, name: str = "this model"
) -> None:
    """A one-line error when per-person prompts are asked of a model without them, or for
    person 1 of a reaction (that person is the user's motion)."""
    if all(p is None for p in own):
        return
    if not takes_person_prompts(config):
        raise UMFError(f"{name} was not trained with per-person prompts (--person): describe "
                       "everyone in the scene prompt")  # fmt: skip
    if acting and own[0] is not None:
        raise UMFError("person 1 is the given motion: person prompts start with person 2")


def person_text(pipe: Any, own: Sequence[str | None], k: int, batch: int) -> dict[str, Any]:
    """Person ``k``'s (0-based) own prompt, encoded for ``batch`` rows, or nothing."""
    prompt = own[k] if k < len(own) else None
    if prompt is None:
        return {}
    words = respell_prompt(prompt, pipe.config.text.respell)
    return {"person_text": pipe.text_encoder.encode([words] * batch).to(pipe.device)}


def person_meta(pipe: Any, own: Sequence[str | None], num_people: int) -> dict[str, Any]:
    """``person_prompts`` (one per person, None: the scene prompt alone) and their
    ``person_coverage``, or nothing when no person has one."""
    own = list(own) + [None] * (num_people - len(own))
    if all(p is None for p in own):
        return {}
    scored = pipe.coverage([p for p in own if p is not None])
    return {"person_prompts": own,
            "person_coverage": [None if p is None else scored.pop(0) for p in own]}  # fmt: skip
