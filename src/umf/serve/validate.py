"""Checks of the JSON fields of ``POST /api/generate``: the CLI's limits, one-line messages.

Kept here rather than shared with the CLI so that an HTTP client gets a 400 with a JSON
message for every bad field before the model is touched; the pipeline's own checks
(``UMFError``) still run after these and are reported the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from umf.pipeline import MAX_PEOPLE

MAX_PROMPT_CHARS = 500
SECONDS_RANGE = (0.5, 10.0)
MAX_SEED = 2**32 - 1
GUIDANCE_RANGE = (0.0, 20.0)
MAX_STEPS = 200  # per P-Flow stage and per added person (S-Flow): bounds a request's time
MAX_STAGES = 8
MAX_START = 3600.0

FIELDS = {
    "prompt", "people", "seconds", "seed", "guidance", "steps", "sflow_steps",
    "actor", "actor_person", "start", "joints", "person_prompts",
}  # fmt: skip


class RequestError(Exception):
    """A bad request: the HTTP status and a one-line message for the client."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class GenerateRequest:
    """One scene to generate, every field checked; ``None`` means the model's default."""

    prompt: str
    people: int = 2
    seconds: float = 4.0
    seed: int = 0
    guidance: float | None = None
    steps: tuple[int, ...] | None = None
    sflow_steps: int | None = None
    actor: str | None = None
    actor_person: int = 1
    start: float = 0.0
    joints: bool = True
    person_prompts: tuple[str | None, ...] = ()  # the K-th for person K; None: scene only


def _int(body: dict[str, Any], name: str, default: int | None, lo: int, hi: int) -> int | None:
    value = body.get(name, default)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, int):
        raise RequestError(f"'{name}' must be an integer, got {value!r}"[:200])
    if not lo <= value <= hi:
        raise RequestError(f"'{name}' must be between {lo} and {hi}, got {value}")
    return value


def _float(
    body: dict[str, Any], name: str, default: float | None, lo: float, hi: float
) -> float | None:
    value = body.get(name, default)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise RequestError(f"'{name}' must be a number, got {value!r}"[:200])
    if not lo <= value <= hi:
        raise RequestError(f"'{name}' must be between {lo:g} and {hi:g}, got {value:g}")
    return float(value)


def _prompt(body: dict[str, Any]) -> str:
    prompt = body.get("prompt")
    if not isinstance(prompt, str):
        raise RequestError("'prompt' is required and must be a string")
    return _text(prompt, "the prompt")


def _text(text: str, what: str) -> str:
    text = " ".join(text.split())
    if not text:
        raise RequestError(f"{what} is empty")
    if len(text) > MAX_PROMPT_CHARS:
        raise RequestError(f"{what} is longer than {MAX_PROMPT_CHARS} characters")
    return text


def _person_prompts(body: dict[str, Any], people: int) -> tuple[str | None, ...]:
    """``person_prompts``: a list, the K-th for person K; null or "" for a person who
    follows the scene prompt alone; at most one per person."""
    value = body.get("person_prompts")
    if value is None:
        return ()
    if not isinstance(value, list):
        raise RequestError("'person_prompts' must be a list of strings (null: scene prompt only)")
    if len(value) > people:
        raise RequestError(f"'person_prompts' has {len(value)} entries for {people} people")
    out: list[str | None] = []
    for k, p in enumerate(value, 1):
        if p is not None and not isinstance(p, str):
            raise RequestError(f"'person_prompts' entry {k} must be a string or null")
        out.append(None if p is None or not p.strip() else _text(p, f"person {k}'s prompt"))
    return tuple(out)


def parse_steps(value: Any) -> tuple[int, ...] | None:
    """``"45,5"`` (as the CLI takes it) or ``[45, 5]``: P-Flow steps per stage."""
    if value is None or value == "":
        return None
    if isinstance(value, str):
        try:
            value = [int(s) for s in value.split(",")]
        except ValueError:
            raise RequestError(f"'steps' takes integers like 45,5, got {value!r}"[:200]) from None
    if not isinstance(value, list) or not value or len(value) > MAX_STAGES:
        raise RequestError(f"'steps' must be 1 to {MAX_STAGES} integers like [45, 5]")
    if any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_STEPS for v in value):
        raise RequestError(f"'steps' must be integers between 1 and {MAX_STEPS}")
    return tuple(value)


def _actor(body: dict[str, Any]) -> str | None:
    actor = body.get("actor")
    if actor is None or actor == "":
        return None
    if not isinstance(actor, str) or len(actor) > 64:
        raise RequestError("'actor' must be the id that POST /api/upload returned")
    return actor


def parse_generate(body: Any) -> GenerateRequest:
    """A checked :class:`GenerateRequest` from a decoded JSON body, or a RequestError."""
    if not isinstance(body, dict):
        raise RequestError("the request body must be a JSON object")
    unknown = sorted(set(body) - FIELDS)
    if unknown:
        raise RequestError(f"unknown field {unknown[0]!r}; fields: {', '.join(sorted(FIELDS))}")
    actor = _actor(body)
    people = _int(body, "people", 2, 2 if actor else 1, MAX_PEOPLE)
    joints = body.get("joints", True)
    if not isinstance(joints, bool):
        raise RequestError("'joints' must be true or false")
    return GenerateRequest(
        prompt=_prompt(body),
        people=people,
        seconds=_float(body, "seconds", 4.0, *SECONDS_RANGE),
        seed=_int(body, "seed", 0, 0, MAX_SEED),
        guidance=_float(body, "guidance", None, *GUIDANCE_RANGE),
        steps=parse_steps(body.get("steps")),
        sflow_steps=_int(body, "sflow_steps", None, 1, MAX_STEPS),
        actor=actor,
        actor_person=_int(body, "actor_person", 1, 1, MAX_PEOPLE),
        start=_float(body, "start", 0.0, 0.0, MAX_START),
        joints=joints,
        person_prompts=_person_prompts(body, people or 2),
    )


REROLL_FIELDS = {"scene", "person", "seed", "joints", "person_prompt"}


@dataclass(frozen=True)
class RerollRequest:
    """One person of a stored scene to generate again (``POST /api/reroll``)."""

    scene: str
    person: int
    seed: int = 0
    joints: bool = True
    person_prompt: str | None = None  # what the person does (None: as the scene recorded)


def parse_reroll(body: Any) -> RerollRequest:
    """A checked :class:`RerollRequest` from a decoded JSON body, or a RequestError."""
    if not isinstance(body, dict):
        raise RequestError("the request body must be a JSON object")
    unknown = sorted(set(body) - REROLL_FIELDS)
    if unknown:
        raise RequestError(f"unknown field {unknown[0]!r}; fields: "
                           f"{', '.join(sorted(REROLL_FIELDS))}")  # fmt: skip
    scene = body.get("scene")
    if not isinstance(scene, str) or not 0 < len(scene) <= 64:
        raise RequestError("'scene' must be the id of a scene (GET /api/scenes)")
    person = _int(body, "person", None, 1, MAX_PEOPLE)
    if person is None:
        raise RequestError("'person' is required: which person to re-roll, 1 for the first")
    joints = body.get("joints", True)
    if not isinstance(joints, bool):
        raise RequestError("'joints' must be true or false")
    own = body.get("person_prompt")
    if own is not None and not isinstance(own, str):
        raise RequestError("'person_prompt' must be a string")
    own = None if own is None or not own.strip() else _text(own, "the person prompt")
    return RerollRequest(scene, person, _int(body, "seed", 0, 0, MAX_SEED), joints, own)
