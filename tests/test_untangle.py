"""Bones moved out of a partner's body: less overlap, rigid bones, nothing else touched."""

from __future__ import annotations

import numpy as np
import pytest

from umf.capsules import capsule_penetration, overlaps
from umf.kinematics import fit_bodies
from umf.untangle import MAX_PUSH, SMOOTH, SPREAD, pushes, smooth, spread, untangle


def _couple(walk: np.ndarray, gap: float) -> np.ndarray:
    """Person 1 walking; person 2 the same walk turned to face them, ``gap`` m ahead of
    person 1's pelvis at every frame (the same floor path, so torsos and arms meet)."""
    turned = walk.copy()
    turned[..., [0, 2]] *= -1  # half a turn about the vertical through the origin...
    pelvis = walk[:, :1].copy()
    pelvis[..., 1] = 0.0
    turned = turned - turned[:, :1] * np.array([1.0, 0.0, 1.0]) + pelvis  # ...on person 1's path
    turned[..., 2] += gap
    return np.stack([walk, turned])


def test_a_couple_overlapping_is_pulled_out_with_rigid_bones(real_joints):
    """Person 2 stands 0.3 m in front of person 1, facing them: torsos and arms overlap.
    untangle lowers the mean overlap by more than half, keeps every bone's length, moves
    only person 2, and only the frames that overlapped (and those a push fades into)."""
    couple = _couple(real_joints.numpy()[:40], 0.3)
    bodies = fit_bodies(couple, floor=None, clean=False)
    before = bodies.joints()
    depth = capsule_penetration(before[1], before[0])
    assert depth.mean() > 0.02
    out = untangle(bodies, movable=True, floor=None)
    after = out.joints()
    assert capsule_penetration(after[1], after[0]).mean() < 0.5 * depth.mean()
    assert np.array_equal(after[0], before[0])  # person 1 never moves
    np.testing.assert_array_equal(out.offsets, bodies.offsets)  # the same bones
    from umf.skeleton import PARENTS

    lengths = [np.linalg.norm(j[:, :, 1:] - j[:, :, PARENTS[1:]], axis=-1) for j in (before, after)]
    np.testing.assert_allclose(lengths[1], lengths[0], atol=1e-9)
    # the pelvis' floor path is kept
    np.testing.assert_allclose(after[1, :, 0, [0, 2]], before[1, :, 0, [0, 2]], atol=1e-6)


def test_people_apart_are_left_exactly_as_they_were(real_joints):
    couple = _couple(real_joints.numpy()[:30], 1.5)
    bodies = fit_bodies(couple, floor=0.0, clean=True)
    out = untangle(bodies)
    np.testing.assert_array_equal(out.rotations, bodies.rotations)
    np.testing.assert_array_equal(out.root, bodies.root)


def test_a_person_not_to_be_cleaned_is_not_moved(real_joints):
    """``react``: a user's own person 2 (movable False) keeps its motion, overlap or not."""
    couple = _couple(real_joints.numpy()[:20], 0.3)
    bodies = fit_bodies(couple, floor=None, clean=False)
    out = untangle(bodies, movable=[True, False], floor=None)
    np.testing.assert_array_equal(out.joints(), bodies.joints())


def test_pushes_follow_the_contact_normal_and_are_capped():
    """Two parallel vertical forearm-like bodies side by side: person a's pushes point away
    from b (+x), are no longer than MAX_PUSH, and the pelvis gets none."""
    a = np.zeros((3, 22, 3))
    a[..., 1] = np.linspace(0.0, 1.7, 22)
    b = a.copy()
    a[..., 0] += 0.05  # 5 cm apart: every capsule pair of the two columns overlaps
    hit = overlaps(a, b)
    assert hit["frame"].size and np.all(hit["normal"][:, 0] > 0)
    push = pushes(a, [b])
    size = np.linalg.norm(push, axis=-1)
    assert size.max() <= MAX_PUSH + 1e-12 and (size[:, 1:] > 0).mean() > 0.8
    assert not push[:, 0].any()
    assert np.all(push[..., 0] >= 0) and np.all(push[..., 0][size > 0] > 0)
    far = a.copy()
    far[..., 0] += 2.0
    assert not pushes(far, [b]).any()


def test_a_frame_keeps_its_own_push_beside_a_bigger_one():
    """A neighbour's larger faded push never replaces a frame's own push (another way)."""
    push = np.zeros((5, 22, 3))
    push[2, 7] = [0.01, 0.0, 0.0]
    push[3, 7] = [0.0, 0.04, 0.0]
    out = spread(push)
    np.testing.assert_array_equal(out[2, 7], push[2, 7])
    np.testing.assert_array_equal(out[3, 7], push[3, 7])
    assert out[1, 7, 1] > 0  # an unpushed frame takes the larger faded neighbour


@pytest.mark.parametrize("frame", [0, 10, 19])
def test_a_push_fades_in_and_out_and_keeps_its_peak(frame):
    push = np.zeros((20, 22, 3))
    push[frame, 5] = [0.04, 0.0, 0.0]
    out = spread(push)
    assert out[frame, 5, 0] == pytest.approx(0.04)
    for lag in range(1, SPREAD + 2):
        for t in (frame - lag, frame + lag):
            if 0 <= t < 20:
                want = 0.04 * max(0.0, 1.0 - lag / (SPREAD + 1))
                assert out[t, 5, 0] == pytest.approx(want)
    assert not np.delete(out, 5, axis=1).any()


def test_the_clean_up_untangles_couples_who_touch_only(real_joints, monkeypatch):
    """clean_up with ``contact`` (a prompt worded like a touching take) untangles the couple
    after the fit; without it (every other prompt, kept apart by the separation anyway)
    the result is the fit's, bit for bit."""
    import umf.clean_up as cu

    couple = _couple(real_joints.numpy()[:40], 0.3).astype(np.float32)
    contacts = np.zeros((2, 40, 4), dtype=np.float32)
    touch = {"pelvis_m": 0.25, "closest_m": 0.02}
    _, untangled = cu.clean_up(couple, contacts, contact=touch)
    _, plain = cu.clean_up(couple, contacts)
    monkeypatch.setattr(cu, "untangle", lambda bodies, *a, **k: bodies)
    _, fitted = cu.clean_up(couple, contacts, contact=touch)
    _, plain_again = cu.clean_up(couple, contacts)
    np.testing.assert_array_equal(plain.joints(), plain_again.joints())
    j, f = untangled.joints(), fitted.joints()
    assert capsule_penetration(f[1], f[0]).mean() > 0.01
    assert capsule_penetration(j[1], j[0]).mean() < 0.5 * capsule_penetration(f[1], f[0]).mean()


def test_only_frames_near_an_overlap_change_and_only_they_are_lifted(real_joints):
    """Person 2 meets person 1 in frames 30-40 only (1.5 m ahead before and after): frames
    more than SPREAD + SMOOTH from them keep their rotations and root bit for bit, even one sunk
    under the floor (only a moved frame is lifted back onto it)."""
    walk = real_joints.numpy()[:70]
    near, far = _couple(walk, 0.3), _couple(walk, 1.5)
    couple = far.copy()
    couple[:, 30:41] = near[:, 30:41]
    bodies = fit_bodies(couple, floor=None, clean=False)
    b = bodies.joints()
    bodies.root[1, 5, 1] -= 0.2  # sunk, far from the overlap
    bodies.root[1, 30:41, 1] -= 0.08  # a little under where it overlaps: lifted back
    out = untangle(bodies, floor=0.0)
    reach = SPREAD + SMOOTH
    still = np.r_[0 : 30 - reach, 41 + reach : 70]
    np.testing.assert_array_equal(out.rotations[:, still], bodies.rotations[:, still])
    np.testing.assert_array_equal(out.root[:, still], bodies.root[:, still])
    j = out.joints()
    window = slice(30, 41)
    assert (capsule_penetration(j[1, window], j[0, window]).mean()
            < 0.5 * capsule_penetration(b[1, window], b[0, window]).mean())  # fmt: skip
    np.testing.assert_allclose(j[1, window, :, 1].min(-1), 0.0, atol=1e-9)  # on the floor
    faded = np.r_[30 - SPREAD : 30, 41 : 41 + SPREAD]  # the pushes fade into these
    assert not np.array_equal(out.rotations[1, faded], bodies.rotations[1, faded])


def test_a_push_goes_to_the_end_of_the_bone_that_is_inside():
    """A forearm whose wrist is inside the partner's chest and whose elbow is clear: the
    wrist is pushed (almost) the whole way, the elbow a little."""
    b = np.zeros((2, 22, 3))
    b[..., 1] = np.linspace(0.0, 1.7, 22)
    a = b + np.array([2.0, 0.0, 0.0])
    a[:, 18] = [0.40, 1.2, 0.0]  # left elbow, clear of the column
    a[:, 20] = [0.02, 1.2, 0.0]  # left wrist, 2 cm from it: inside
    push = pushes(a, [b])
    wrist, elbow = np.linalg.norm(push[:, 20], axis=-1), np.linalg.norm(push[:, 18], axis=-1)
    assert np.all(wrist > 0.04) and np.all(wrist > 3 * elbow)
    assert np.all(push[:, 20, 0] > 0)  # out of the column, along +x


def test_each_person_moves_out_of_those_before_them_only(real_joints):
    """Three people: persons 2 and 3 overlap each other, person 1 is far from both. Person 2
    owes nothing to person 3 (it was there first) and stays bit for bit; person 3 moves."""
    walk = real_joints.numpy()[:20]
    pair = _couple(walk, 0.3)
    group = np.stack([walk + np.array([5.0, 0.0, 0.0]), pair[0], pair[1]])
    bodies = fit_bodies(group, floor=None, clean=False)
    out = untangle(bodies, floor=None)
    np.testing.assert_array_equal(out.joints()[:2], bodies.joints()[:2])
    j = out.joints()
    assert (
        capsule_penetration(j[2], j[1]).mean()
        < 0.5 * capsule_penetration(bodies.joints()[2], bodies.joints()[1]).mean()
    )


def test_movable_must_name_every_person(real_joints):
    bodies = fit_bodies(_couple(real_joints.numpy()[:5], 0.3), floor=None, clean=False)
    with pytest.raises(ValueError, match="movable names 1 people"):
        untangle(bodies, movable=[True])


def test_smoothing_averages_pushes_and_keeps_a_steady_one():
    """A steady push stays as it is; a one-frame spike is spread over 2 SMOOTH + 1 frames
    with triangle weights that sum to the spike (nothing is pushed twice)."""
    steady = np.zeros((12, 22, 3))
    steady[:, 4] = [0.0, 0.0, 0.03]
    np.testing.assert_allclose(smooth(steady), steady)
    spike = np.zeros((12, 22, 3))
    spike[6, 4, 0] = 0.03
    out = smooth(spike)
    assert out[6, 4, 0] == pytest.approx(0.03 * (SMOOTH + 1) / (SMOOTH + 1) ** 2)
    assert out[:, 4, 0].sum() == pytest.approx(0.03)
    assert not out[: 6 - SMOOTH].any() and not out[7 + SMOOTH :].any()
