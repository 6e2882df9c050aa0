"""Keeping generated people apart: rigid floor shifts only, and only as much as needed."""

from __future__ import annotations

import numpy as np

from umf.separation import MIN_DISTANCE, closest_approach, separate_people


def _pelvis_gaps(joints: np.ndarray) -> list[float]:
    p = joints[:, :, 0, [0, 2]]
    return [closest_approach(p[k], p[j])[0] for k in range(len(p)) for j in range(k)]


def test_overlapping_people_are_pushed_apart_rigidly(real_joints):
    walk = real_joints.numpy()[:90]
    scene = np.stack([walk, walk, walk + np.array([0.1, 0.0, 0.0]), walk])  # 3 on top of 1
    out, shifts = separate_people(scene)
    assert min(_pelvis_gaps(out)) >= MIN_DISTANCE - 1e-6
    assert np.allclose(shifts[0], 0.0)  # person 1 never moves
    assert np.allclose(shifts[:, 1], 0.0)  # nobody is lifted
    for k in range(4):  # each motion is its own up to one translation
        assert np.allclose(out[k] - scene[k], shifts[k], atol=1e-6)


def test_people_already_apart_do_not_move(real_joints):
    walk = real_joints.numpy()[:90]
    scene = np.stack([walk, walk + np.array([1.0, 0.0, 0.0])])
    out, shifts = separate_people(scene)
    assert np.array_equal(out, scene) and not shifts.any()


def test_shift_is_minimal_for_two_people(real_joints):
    walk = real_joints.numpy()[:60]
    scene = np.stack([walk, walk + np.array([0.3, 0.0, 0.0])])  # 0.3 m apart all along
    _, shifts = separate_people(scene)
    assert np.allclose(shifts[1], [MIN_DISTANCE - 0.3 + 1e-3, 0.0, 0.0], atol=1e-5)


def test_a_crowd_always_ends_apart():
    """Ten people starting in a heap: pushes between neighbours alone can cycle."""
    from umf.separation import separation_shifts

    for seed in range(40):
        rng = np.random.default_rng(seed)
        steps = rng.normal(scale=0.02, size=(10, 30, 2))
        pelvis = rng.normal(scale=0.3, size=(10, 1, 2)) + np.cumsum(steps, 1)
        placed = pelvis + separation_shifts(pelvis)[:, None]
        gaps = [np.linalg.norm(placed[i] - placed[j], axis=-1).min()
                for i in range(10) for j in range(i)]  # fmt: skip
        assert min(gaps) >= 0.5 - 1e-6, seed


def test_non_finite_paths_do_not_hang():
    """NaN never 'clears' anybody: separation must still return (the caller reports it)."""
    from umf.separation import separation_shifts

    assert np.isfinite(separation_shifts(np.full((3, 5, 2), np.nan))).all()
