"""The pipeline's clean-up of a batch of scenes (`umf.clean_up.clean_up_scenes`): scene by
scene, or every person of every scene in one fit (what a GPU does), with the same result."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import MODULE
from umf.clean_up import clean_up, clean_up_scenes


@pytest.fixture(scope=MODULE)
def batch(bandai_clips):
    """Three two-person scenes of real motion, 40 frames, feet sunk 2 cm and planted in
    part, people 0.8 m apart in one scene and 0.1 m (overlapping) in another."""
    ids = ["dataset-1_bow_normal_001", "dataset-1_walk_normal_001", "dataset-1_kick_normal_001"]
    clips = {c.id: c.joints[0][:40].astype(np.float64) for c in bandai_clips if c.id in ids}
    for j in clips.values():  # each starts at the origin of the floor
        j[..., [0, 2]] -= j[0, 0, [0, 2]]
    scenes, contacts = [], []
    for k, (a, b) in enumerate([(0, 1), (1, 2), (2, 0)]):
        one, two = clips[ids[a]].copy(), clips[ids[b]].copy()
        two[..., 0] += 0.8 if k != 1 else 0.1
        pair = np.stack([one, two])
        pair[..., 1] -= pair[..., 1].min() + 0.02
        scenes.append(pair)
        c = np.zeros((2, 40, 4))
        c[0, 5 + 3 * k : 30, :2] = 1.0  # every person of every scene planted differently,
        c[1, 12 : 36 - 4 * k, 2:] = 1.0  # so a fit that mixed them up would show
        contacts.append(c)
    return np.stack(scenes), np.stack(contacts)


@pytest.mark.parametrize("clean", [[True, True], [False, True]])  # an actor, as in react
def test_merged_fit_matches_scene_by_scene(batch, clean):
    decoded, contacts = batch
    one_by_one = clean_up_scenes(decoded, contacts, 0.0, clean, merge=False)
    merged = clean_up_scenes(decoded, contacts, 0.0, clean, merge=True, device="cpu")
    np.testing.assert_array_equal(one_by_one[0], merged[0])
    assert one_by_one[0][1].any()  # the overlapping pair was separated
    for a, b in zip(one_by_one[1], merged[1], strict=True):
        assert a.num_people == b.num_people == 2
        np.testing.assert_allclose(a.joints(), b.joints(), atol=1e-7)
        np.testing.assert_allclose(a.offsets, b.offsets, atol=1e-12)
    # the contacts reach their own person: another person's would pin other frames
    swapped = clean_up_scenes(decoded, contacts[:, ::-1].copy(), 0.0, [True, True], merge=True)
    assert max(np.abs(a.joints() - b.joints()).max()
               for a, b in zip(swapped[1], merged[1], strict=True)) > 1e-4  # fmt: skip
    # one scene is a batch of one
    shifts, bodies = clean_up(decoded[2], contacts[2], 0.0, clean)
    np.testing.assert_array_equal(shifts, one_by_one[0][2])
    np.testing.assert_array_equal(bodies.joints(), one_by_one[1][2].joints())


def test_a_gpu_device_merges_and_per_person_flags_follow_each_scene(batch, monkeypatch):
    import umf.clean_up as P

    decoded, contacts = batch
    calls = []
    real = P.fit_bodies

    def spy(joints, contacts, floor, clean, **kw):
        calls.append((joints.shape[0], list(clean), kw.get("device")))
        return real(joints, contacts, floor, clean)

    monkeypatch.setattr(P, "fit_bodies", spy)
    # an actor (person 1 not cleaned), as a reaction scene has
    clean_up_scenes(decoded, contacts, 0.0, [False, True], merge=True, device="cpu")
    assert calls == [(6, [False, True] * 3, "cpu")]
    calls.clear()
    clean_up_scenes(decoded, contacts, 0.0, [False, True], device="cpu")
    assert [c[0] for c in calls] == [2, 2, 2]
    calls.clear()
    clean_up_scenes(decoded, contacts, 0.0, True, fit=False, merge=True)
    assert calls == []  # nothing to fit
    # a GPU merges by default (the spy fits on the CPU: no GPU needed to see the choice)
    clean_up_scenes(decoded, contacts, 0.0, True, device=torch.device("cuda"))
    assert calls == [(6, [True] * 6, torch.device("cuda"))]
