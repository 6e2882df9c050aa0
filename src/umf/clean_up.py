"""What the pipeline does to decoded joints before anything is written: planted feet
anchored, people kept apart, one rigid body each (``docs/cleanup.md``). The pipeline calls
:func:`clean_up_scenes` on every batch it samples; :func:`delivered_joints` redoes it for a
scene sampled without it (evaluation scores both)."""

from __future__ import annotations

import numpy as np
import torch

from umf.anchoring import anchor_people
from umf.kinematics import Bodies, fit_bodies
from umf.separation import separate_people, touching_distances
from umf.untangle import untangle


def clean_up(
    decoded: np.ndarray,
    contacts: np.ndarray,
    floor: float = 0.0,
    clean: bool | list[bool] = True,
    anchor: bool = True,
    separate: bool = True,
    fit: bool = True,
    contact: dict | None = None,
) -> tuple[np.ndarray, Bodies | None]:
    """What the pipeline does to one scene's decoded joints (N, T, 22, 3) with contact
    labels (N, T, 4) before anything is written, in this order:

    1. ``anchor`` (only with ``fit``): people with ``clean`` moved back by the slide of a
       planted foot (:mod:`umf.anchoring`), with ``contact`` people 1 and 2 together by
       their mean;
    2. ``separate``: people 2..N shifted rigidly apart on the floor (:mod:`umf.separation`),
       judged on the anchored paths; with ``contact`` (the prompt is worded like a real
       take whose people touch, from the model's vocabulary; only its presence counts,
       :func:`umf.separation.touching_distances`) only as far as real partners ever keep
       apart, so partners may touch;
    3. ``fit``: one rigid body each, planted feet pinned and people with ``clean`` kept off
       the ``floor`` (:mod:`umf.kinematics`); with ``contact`` (and ``separate``), people
       2..N with ``clean`` then move their limbs out of the bodies of those before them
       (:mod:`umf.untangle`).

    Returns the (N, 3) separation shifts and the bodies (None without ``fit``).
    """
    shifts, bodies = clean_up_scenes(decoded[None], contacts[None], floor, clean, anchor,
                                     separate, fit, [contact])  # fmt: skip
    return shifts[0], bodies[0]


def place_people(
    decoded: np.ndarray,
    contacts: np.ndarray,
    floor: float = 0.0,
    clean: bool | list[bool] = True,
    anchor: bool = True,
    separate: bool = True,
    contact: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1 and 2 of :func:`clean_up` for one scene: the joints (N, T, 22, 3) anchored
    (with ``anchor``) and the (N, 3) separation shifts, not yet added to them."""
    held = 2 if contact else 0  # the couple a prompt holds together moves as one
    start = anchor_people(decoded, contacts, floor, clean, together=held) if anchor else decoded
    shifts = np.zeros((decoded.shape[0], 3), dtype=np.float32)
    if separate and decoded.shape[0] > 1:
        _, shifts = separate_people(start, **touching_distances(contact))
    return start, shifts


def clean_up_scenes(
    decoded: np.ndarray,
    contacts: np.ndarray,
    floor: float = 0.0,
    clean: bool | list[bool] = True,
    anchor: bool = True,
    separate: bool = True,
    fit: bool = True,
    contact: list[dict | None] | None = None,
    device: str | torch.device | None = None,
    merge: bool | None = None,
) -> tuple[np.ndarray, list[Bodies | None]]:
    """:func:`clean_up` for B scenes (B, N, T, 22, 3), contacts (B, N, T, 4), ``contact``
    one entry per scene: the (B, N, 3) shifts and each scene's bodies.

    Anchoring and separation run scene by scene. ``merge`` (default: on a GPU ``device``)
    fits every person of every scene in one solve on ``device``, thousands of poses at
    once; otherwise the fit too runs scene by scene, which is faster on a CPU (merging 16
    scenes took 1.4-1.6x the time here: the bigger systems leave the cache). Each person's
    fit is its own either way (bone lengths, pins, floor are per person).
    """
    b, n = decoded.shape[:2]
    near = [None] * b if contact is None else list(contact)
    shifts = np.zeros((b, n, 3), dtype=np.float32)
    placed = []
    for i in range(b):
        start, shifts[i] = place_people(decoded[i], contacts[i], floor, clean, anchor and fit,
                                        separate, near[i])  # fmt: skip
        placed.append(start + shifts[i][:, None, None, :])
    if not fit:
        return shifts, [None] * b
    if merge is None:
        merge = device is not None and torch.device(device).type == "cuda"
    flags = [bool(clean)] * n if isinstance(clean, bool) else [bool(c) for c in clean]
    if not merge:
        bodies = [fit_bodies(p, c, floor, clean) for p, c in zip(placed, contacts, strict=True)]
    else:
        every = fit_bodies(np.concatenate(placed), contacts.reshape(b * n, *contacts.shape[2:]),
                           floor, flags * b, device=device)  # fmt: skip
        people = [slice(i * n, (i + 1) * n) for i in range(b)]
        bodies = [Bodies(every.offsets[p], every.rotations[p], every.root[p]) for p in people]
    # a couple let as close as real partners come: limbs moved out of the partner's body
    return shifts, [untangle(bd, flags, floor) if near[i] and separate and n > 1 else bd
                    for i, bd in enumerate(bodies)]  # fmt: skip


def delivered_joints(
    raw: np.ndarray, contacts: np.ndarray, floor: float = 0.0, anchor: bool = True
) -> np.ndarray:
    """A generated scene's joints as the default pipeline hands them out, from its raw
    decoded joints (N, T, 22, 3) and contact labels (N, T, 4): :func:`clean_up` with
    separation and the fit, so evaluation can score a ``fit=False`` scene both raw and as
    users receive it (``pipe(..., anchor=anchor)``).
    """
    _, bodies = clean_up(np.asarray(raw), np.asarray(contacts), floor, True, anchor)
    return bodies.joints()
