"""Anchoring planted feet: a gliding body stops gliding, a real walk keeps its path."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from umf import anchoring as A
from umf.eval.physics import foot_skating
from umf.representation import foot_contacts
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT


def _clip(bandai_clips, cid: str) -> np.ndarray:
    joints = next(c for c in bandai_clips if c.id == cid).joints[0].astype(np.float64)
    joints[..., 1] -= joints[..., 1].min()  # on the floor
    return joints


def _contacts(joints: np.ndarray) -> np.ndarray:
    """InterGen contact labels for every frame (the last frame repeats the one before)."""
    c = foot_contacts(torch.from_numpy(joints)).numpy()
    return np.concatenate([c, c[-1:]], axis=0)


def _path_length(joints: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=-1).sum())


def test_a_gliding_standing_person_stops(bandai_clips):
    """A real bow dragged 1 m along the floor with its feet labelled planted: anchored,
    the feet and the pelvis stand still again; the pose and the heights are untouched."""
    bow = _clip(bandai_clips, "dataset-1_bow_normal_001")[:90]
    contacts = _contacts(bow)
    glide = bow.copy()
    glide[..., 0] += np.linspace(0.0, 1.0, len(bow))[:, None]  # 1 m over 3 s, feet included
    fixed, shift = A.anchor_feet(glide, contacts, smooth=0.0)
    assert _path_length(glide) > 1.0
    assert _path_length(fixed) < _path_length(bow) + 0.02  # the glide is gone
    assert np.allclose(fixed - fixed[:, :1], glide - glide[:, :1])  # same pose
    assert np.allclose(fixed[..., 1], glide[..., 1]) and np.all(shift[:, 1] == 0)
    assert np.allclose(shift[0], 0.0)
    before = foot_skating(glide, 30.0)["grounded_speed"]
    after = foot_skating(fixed, 30.0)["grounded_speed"]
    assert before > 0.3 and after < 0.05


LOCOMOTION = ("dataset-1_walk_normal_001", "dataset-1_walk_normal_002", "dataset-1_walk_sad_001",
              "dataset-2_run_normal_001", "dataset-2_walk-turn-left_active_001")  # fmt: skip


@pytest.mark.parametrize("cid", LOCOMOTION)
def test_real_walks_keep_their_path(bandai_clips, cid):
    """Real planted feet barely slide: every walk and run of the sample keeps at least
    93 % of its distance (the figure anchoring.py quotes), moved by at most a tenth of it."""
    walk = _clip(bandai_clips, cid)
    fixed, shift = A.anchor_feet(walk, _contacts(walk))
    disp = np.linalg.norm(walk[-1, 0, [0, 2]] - walk[0, 0, [0, 2]])
    kept = np.linalg.norm(fixed[-1, 0, [0, 2]] - fixed[0, 0, [0, 2]]) / disp
    assert disp > 1.0 and 0.93 <= kept <= 1.0  # shorter, never longer: slides taken out
    assert np.abs(shift).max() < 0.1 * disp


def test_the_slower_planted_foot_stands(bandai_clips):
    """Both feet planted, the right one sliding 30 cm: the still left foot stands, so the
    correction is the left foot's few millimetres, not the right foot's slide."""
    bow = _clip(bandai_clips, "dataset-1_bow_normal_001")[:40]
    moved = bow.copy()
    moved[:, list(FOOT_RIGHT), 0] += np.linspace(0, 0.3, 40)[:, None]
    slides = A.foot_slides(moved, np.ones((40, 2, 2), dtype=bool))
    steps = np.diff(moved[:, [*FOOT_LEFT, *FOOT_RIGHT]][..., [0, 2]], axis=0)
    assert np.allclose(np.linalg.norm(slides, axis=-1), np.linalg.norm(steps, axis=-1).min(-1))
    assert np.linalg.norm(slides, axis=-1).max() < 0.3 / 39 / 2  # never the sliding foot
    fixed, _ = A.anchor_feet(moved, np.ones((40, 4)), smooth=0.0)
    assert _path_length(fixed) < _path_length(bow) + 0.01


def test_labels_and_height_both_decide():
    """No contact label, or a foot above the contact height: nothing is planted, nothing
    moves."""
    t = 20
    joints = np.zeros((t, 22, 3))
    joints[:, :, 0] = np.linspace(0, 1, t)[:, None]  # sliding along X
    joints[:, list(FOOT_LEFT) + list(FOOT_RIGHT), 1] = 0.01
    fixed, shift = A.anchor_feet(joints, np.zeros((t, 4)))
    assert np.array_equal(fixed, joints) and not shift.any()
    lifted = joints.copy()
    lifted[..., 1] += 0.5  # labelled planted but half a metre up
    fixed, shift = A.anchor_feet(lifted, np.ones((t, 4)))
    assert not shift.any()
    fixed, shift = A.anchor_feet(joints, np.ones((t, 4)), smooth=0.0)
    assert np.allclose(fixed[:, 0, 0], 0.0)  # planted and labelled: held at the start
    raised = joints.copy()
    raised[..., 1] += 1.0  # the same scene on a floor 1 m up
    fixed_up, _ = A.anchor_feet(raised, np.ones((t, 4)), floor=1.0, smooth=0.0)
    assert np.allclose(fixed_up[:, 0, 0], 0.0)


def test_user_motion_is_left_alone(bandai_clips):
    bow = _clip(bandai_clips, "dataset-1_bow_normal_001")[:30]
    glide = bow + np.linspace(0, 0.5, 30)[:, None, None] * np.array([1.0, 0.0, 0.0])
    scene = np.stack([glide, glide])
    contacts = np.stack([_contacts(glide)] * 2)
    out = A.anchor_people(scene, contacts, clean=[False, True])
    assert np.array_equal(out[0], glide)
    assert _path_length(out[1]) < _path_length(glide) - 0.3


@pytest.mark.parametrize("smooth", [0.0, A.SMOOTH])
def test_smoothing_keeps_the_total_correction(bandai_clips, smooth):
    """Smoothing spreads the correction in time; a glide is still taken out in full."""
    bow = _clip(bandai_clips, "dataset-1_bow_normal_001")[:90]
    glide = bow.copy()
    glide[..., 2] += np.linspace(0.0, 0.6, 90)[:, None]
    fixed, _ = A.anchor_feet(glide, _contacts(bow), smooth=smooth)
    net = np.linalg.norm(fixed[-1, 0, [0, 2]] - bow[-1, 0, [0, 2]])
    assert net < 0.05


def test_people_held_together_move_as_one(bandai_clips):
    """A couple, one gliding 0.5 m and one standing: anchored one by one, the glider moves
    back and the gap between them changes; held together, both move by the mean of their
    corrections and the gap is the decoder's at every frame. A third person, not held,
    is anchored on its own; beside a user's own motion the couple is anchored one by one."""
    bow = _clip(bandai_clips, "dataset-1_bow_normal_001")[:30]
    glide = bow + np.linspace(0, 0.5, 30)[:, None, None] * np.array([1.0, 0.0, 0.0])
    partner = bow + np.array([0.0, 0.0, 0.6])
    third = glide + np.array([0.0, 0.0, -0.8])
    scene = np.stack([glide, partner, third])
    contacts = np.stack([_contacts(glide), _contacts(partner), _contacts(third)])
    gap = scene[1, :, 0] - scene[0, :, 0]
    apart = A.anchor_people(scene, contacts)
    assert np.abs((apart[1, :, 0] - apart[0, :, 0]) - gap).max() > 0.3
    held = A.anchor_people(scene, contacts, together=2)
    np.testing.assert_allclose(held[1, :, 0] - held[0, :, 0], gap, atol=1e-9)
    own = [A.anchor_feet(p, c)[1] for p, c in zip(scene, contacts, strict=True)]
    np.testing.assert_allclose(held[0] - scene[0], np.broadcast_to(np.mean(own[:2], 0)[:, None],
                               scene[0].shape), atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(held[2], apart[2], atol=1e-12)  # not held: its own correction
    actor = A.anchor_people(scene, contacts, clean=[False, True, True], together=2)
    np.testing.assert_allclose(actor, A.anchor_people(scene, contacts, clean=[False, True, True]))
