"""Per-person prompts at sampling time: each person's own prompt as a flow's sampler takes
it, and what a scene records of them (the prompts and their coverage)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from umf.text import respell_prompt


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
