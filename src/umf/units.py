"""Which unit a motion file is in, read from the size of the body in it.

A file's unit is the one that gives its body an adult's joint span (toe or ankle to head
along the bones); files in no known unit are scaled to a nominal adult. Used by every
motion reader (BVH, npz, mocap libraries) and by the API's actor check."""

from __future__ import annotations

import numpy as np

from umf.errors import UMFError

# metres per file unit; "cmu" is the CMU ASF unit (0.45 inch^-1 ... i.e. 1/0.45 inches)
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "cmu": 0.0254 / 0.45}
# Span of a standing adult's joints (toe/ankle to head joint), metres: what a unit must give.
STATURE_SPAN = (1.25, 2.1)
NOMINAL_SPAN = 1.5  # where a body is scaled to when no unit gives a plausible span
# Spans (file units) a body in metres may have where no unit gives an adult's: from a doll
# to a statue (and random test data). Outside, and in no unit, a file is refused: a body
# 10,000 times an adult's size is no motion of a person
METRES_SPAN = (0.1, 100.0)


def body_span(joints: np.ndarray) -> float:
    """Height of the joint chain toe/ankle -> head along the bones, in file units: the
    median over frames of leg + spine + neck lengths, so it does not depend on the pose."""
    j = np.asarray(joints, np.float64).reshape(-1, 22, 3)
    chain = (7, 4, 1, 0, 3, 6, 9, 12, 15)  # left ankle up the leg, then the spine to the head
    span = np.median(np.linalg.norm(np.diff(j[:, chain], axis=1), axis=-1).sum(-1))
    if not np.isfinite(span) or span <= 0:
        raise UMFError("the motion has no extent (all joints at one point): not a body")
    return float(span)


def choose_unit(joints: np.ndarray) -> tuple[float, str]:
    """Metres per file unit and how it was chosen: the named unit that gives an adult's
    joint span (:data:`STATURE_SPAN`, nearest :data:`NOMINAL_SPAN` in log scale), else a
    stature scale that gives exactly the nominal span."""
    span = body_span(joints)
    fits = [(abs(np.log(span * u / NOMINAL_SPAN)), name, u) for name, u in UNITS.items()
            if STATURE_SPAN[0] <= span * u <= STATURE_SPAN[1]]  # fmt: skip
    if fits:
        _, name, u = min(fits)
        return u, name
    return NOMINAL_SPAN / span, "stature"


def check_body_size(joints: np.ndarray, name: str, what: str) -> None:
    """Refuse joints (..., 22, 3) in metres (a umf .npz, the API's actor) whose body is of no
    person's size in metres nor in a unit :data:`UNITS` names; ``name``: the unit
    :func:`choose_unit` chose (the span is read again only where none fitted)."""
    if name != "stature":
        return
    span = body_span(joints)
    if not METRES_SPAN[0] <= span <= METRES_SPAN[1]:
        raise UMFError(f"{what}: a body {span:.3g} units tall, a person's size in no unit umf "
                       f"knows ({', '.join(UNITS)})")  # fmt: skip
