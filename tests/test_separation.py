"""Keeping generated people apart: rigid floor shifts only, and only as much as needed."""

from __future__ import annotations

import numpy as np

from umf.data.relations import CONTACT_DISTANCE, closest_joints
from umf.separation import FIT_MARGIN, MIN_DISTANCE, closest_approach, separate_people


def closest_gap(joints: np.ndarray) -> float:
    """Brute force, every joint pair of every two people at every frame (the oracle)."""
    n = len(joints)
    return min(np.linalg.norm(joints[a][:, :, None] - joints[b][:, None], axis=-1).min()
               for a in range(n) for b in range(a + 1, n))  # fmt: skip


def _pelvis_gaps(joints: np.ndarray) -> list[float]:
    p = joints[:, :, 0, [0, 2]]
    return [closest_approach(p[k], p[j])[0] for k in range(len(p)) for j in range(k)]


def test_overlapping_people_are_pushed_apart_rigidly(real_joints):
    walk = real_joints.numpy()[:90]
    scene = np.stack([walk, walk, walk + np.array([0.1, 0.0, 0.0]), walk])  # 3 on top of 1
    out, shifts = separate_people(scene)
    assert min(_pelvis_gaps(out)) >= MIN_DISTANCE - 1e-6
    assert closest_gap(out) >= CONTACT_DISTANCE - 1e-6  # no joint touches
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
    """Pelvises 0.3 m apart: pushed sideways, along the line between them, until both rules
    hold (joints: the contact distance plus the fit's margin), and 2 cm less (a push goes
    STEP_MARGIN = 1 cm beyond what is missing) would break one: the swinging hands come
    closest, not the pelvises."""
    walk = real_joints.numpy()[:60]
    scene = np.stack([walk, walk + np.array([0.3, 0.0, 0.0])])  # 0.3 m apart all along
    out, shifts = separate_people(scene)
    assert np.allclose(shifts[1, 1:], 0.0, atol=1e-9) and shifts[1, 0] > MIN_DISTANCE - 0.3
    apart = CONTACT_DISTANCE + FIT_MARGIN
    assert min(_pelvis_gaps(out)) >= MIN_DISTANCE - 1e-6
    assert closest_gap(out) >= apart - 1e-6
    less = out.copy()
    less[1, ..., 0] -= 0.02
    assert min(_pelvis_gaps(less)) < MIN_DISTANCE or closest_gap(less) < apart


def test_reaching_arms_are_kept_out_of_a_neighbour(bandai_clips):
    """Pelvises far enough apart, but a raised arm of one passes 10 cm from the other's
    head: the second person is moved until no two joints are within the contact distance."""
    wave = next(c for c in bandai_clips if c.id == "dataset-2_wave-right-hand_normal_001")
    body = wave.joints[0][:90].astype(np.float64)
    body -= body[:1, :1] * np.array([1.0, 0.0, 1.0])  # start at the origin
    near = body + np.array([0.6, 0.0, 0.0])
    scene = np.stack([body, near])
    assert min(_pelvis_gaps(scene)) > MIN_DISTANCE  # the old rule alone would not move it
    assert closest_gap(scene) < CONTACT_DISTANCE
    out, shifts = separate_people(scene)
    assert closest_gap(out) >= CONTACT_DISTANCE - 1e-6
    assert np.linalg.norm(shifts[1]) > 0 and not shifts[0].any()
    assert np.allclose(out[1] - scene[1], shifts[1])


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


def test_bodies_alone_still_end_apart():
    """With no pelvis rule (min_distance 0), bodies pressed together from both sides (the
    pushes cancel) still end apart: the walk-out steps by the contact distance."""
    from umf.separation import separation_shifts

    bodies = np.zeros((3, 4, 22, 3))
    bodies[..., 1] = np.linspace(0.0, 1.7, 22)  # a vertical pole of joints per person
    bodies[0, ..., 0], bodies[1, ..., 0], bodies[2, ..., 0] = -0.25, 0.25, 0.0
    shifts = separation_shifts(bodies[:, :, 0, [0, 2]], 0.0, bodies=bodies,
                               contact_distance=0.28)  # fmt: skip
    placed = bodies + np.stack([shifts[:, 0], np.zeros(3), shifts[:, 1]], -1)[:, None, None]
    assert closest_gap(placed) >= 0.28 - 1e-6


def test_closest_joints_agrees_with_brute_force():
    """The reach bound never skips a frame that holds the closest pair (random bodies,
    1-5 frames, any ``within``), and the matmul distances pick the true pair."""
    rng = np.random.default_rng(0)
    for _ in range(300):
        t = int(rng.integers(1, 6))
        a = rng.normal(scale=0.3, size=(t, 22, 3)) + rng.normal(scale=1.0, size=3)
        b = rng.normal(scale=0.3, size=(t, 22, 3)) + rng.normal(scale=1.0, size=3)
        true = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1)
        within = float(rng.uniform(0.0, 2.0))
        d, f, way = closest_joints(a, b, within)
        if true.min() < within:  # searched: the exact minimum, its frame and direction
            assert np.isclose(d, true.min()) and np.isclose(true[f].min(), true.min())
            assert np.linalg.norm(way) <= d + 1e-9
        else:  # not within: only said to be at least ``within`` (what the caller needs)
            assert d >= within
        assert np.isclose(closest_joints(a, b)[0], true.min())


def test_the_smallest_shift_is_shorter_and_still_clears():
    """``smallest`` (touching prompts): person 2's shift is never longer than the push, still
    keeps every frame's pelvis ``min_distance`` and joints ``contact_distance`` from person
    1, and is shorter in scenes where the worst frame points the push the long way out."""
    from umf.separation import separation_shifts

    rng = np.random.default_rng(3)
    shorter = 0
    for _ in range(12):
        bodies = np.zeros((2, 6, 22, 3))
        bodies[..., 1] = np.linspace(0.0, 1.7, 22)
        bodies[0, :, :, [0, 2]] = rng.normal(0.0, 0.02, (2, 6, 1))  # person 1 about the origin
        bodies[1, :, :, [0, 2]] = rng.normal(0.0, 0.25, (2, 6, 1))  # person 2 roams through
        bodies[:, :, 5:, 0] += rng.normal(0.0, 0.15, (2, 6, 17))  # arms reach out sideways
        pelvis = bodies[:, :, 0, [0, 2]]
        kw = {"bodies": bodies, "contact_distance": 0.1}
        push = separation_shifts(pelvis, 0.29, **kw)
        small = separation_shifts(pelvis, 0.29, smallest=True, **kw)
        assert np.linalg.norm(small[1]) <= np.linalg.norm(push[1]) + 1e-12
        placed = bodies + np.stack([small[:, 0], np.zeros(2), small[:, 1]], -1)[:, None, None]
        assert closest_gap(placed) >= 0.1 - 1e-9
        gap = np.linalg.norm(placed[1, :, 0, [0, 2]] - placed[0, :, 0, [0, 2]], axis=0)
        assert gap.min() >= 0.29 - 1e-9
        shorter += np.linalg.norm(small[1]) < 0.95 * np.linalg.norm(push[1])
    assert shorter >= 3, shorter
