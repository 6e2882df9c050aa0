"""Keep generated people apart: a rigid shift on the floor, never a change of the motion.

S-Flow is trained on two-person scenes; asked for a third or fourth person it can place
several reactions on top of each other (they share the same context). An animator wants
bodies that do not overlap, so the pipeline, by default, moves each person k >= 2 as a
whole along the floor, as little as needed, until their pelvis path keeps ``min_distance``
from everyone before them at every frame. Person 1 never moves (in ``react`` mode it is
the user's own motion), and each person's motion is unchanged up to that one translation.
Evaluation turns it off (``separate=False``) to score the model's own output.
"""

from __future__ import annotations

import numpy as np

MIN_DISTANCE = 0.5  # metres between two pelvises on the floor: shoulder to shoulder


def closest_approach(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Smallest floor distance between two pelvis paths (T, 2) and the frame where it is."""
    d = np.linalg.norm(a - b, axis=-1)
    t = int(np.argmin(d))
    return float(d[t]), t


def separation_shifts(
    pelvis: np.ndarray, min_distance: float = MIN_DISTANCE, max_rounds: int = 50
) -> np.ndarray:
    """Floor offsets (N, 2) that keep pelvis paths (N, T, 2) ``min_distance`` apart.

    People are placed in order (as Algorithm 1 generates them); person k is pushed away
    from the earlier person it comes closest to, along the line between them at that
    frame, until it clears all of them. Coincident paths are split along a fixed,
    person-dependent direction so the result is deterministic.
    """
    n = pelvis.shape[0]
    shifts = np.zeros((n, 2))
    for k in range(1, n):
        for _ in range(max_rounds):
            path = pelvis[k] + shifts[k]
            worst = None
            for j in range(k):
                d, t = closest_approach(path, pelvis[j] + shifts[j])
                if d < min_distance and (worst is None or d < worst[0]):
                    worst = (d, t, j)
            if worst is None:
                break
            d, t, j = worst
            away = path[t] - (pelvis[j, t] + shifts[j])
            if d < 1e-6:
                angle = 2.0 * np.pi * k / (n + 1)
                away = np.array([np.cos(angle), np.sin(angle)])
            shifts[k] += away / max(np.linalg.norm(away), 1e-9) * (min_distance - d + 1e-3)
        _walk_out(pelvis, shifts, k, min_distance)
    return shifts


def _walk_out(pelvis: np.ndarray, shifts: np.ndarray, k: int, min_distance: float) -> None:
    """Pushes between two neighbours can cycle in a crowd: then move person k straight away
    from the others' centre until it clears all of them (always ends: they are finite)."""

    def clear() -> bool:
        path = pelvis[k] + shifts[k]
        return all(
            closest_approach(path, pelvis[j] + shifts[j])[0] >= min_distance for j in range(k)
        )

    if clear() or not np.isfinite(pelvis[: k + 1]).all():  # NaN never clears: leave it
        return
    centre = np.mean([(pelvis[j] + shifts[j]).mean(0) for j in range(k)], axis=0)
    away = (pelvis[k] + shifts[k]).mean(0) - centre
    if np.linalg.norm(away) < 1e-6:
        angle = 2.0 * np.pi * k / (k + 2)
        away = np.array([np.cos(angle), np.sin(angle)])
    away = away / np.linalg.norm(away)
    while not clear():
        shifts[k] += away * (min_distance / 4)


def separate_people(
    joints: np.ndarray, min_distance: float = MIN_DISTANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (N, T, 22, 3) with people k >= 2 shifted apart on the floor, and the (N, 3)
    shifts applied (zero rows for people who did not move)."""
    pelvis = joints[:, :, 0, [0, 2]].astype(np.float64)
    flat = separation_shifts(pelvis, min_distance)
    shifts = np.zeros((joints.shape[0], 3), dtype=joints.dtype)
    shifts[:, 0], shifts[:, 2] = flat[:, 0], flat[:, 1]
    return joints + shifts[:, None, None, :], shifts
