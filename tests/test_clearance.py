"""Keeping person k >= 3 off everybody's whole body (``sflow.warm_clear``): the contact test
against brute force, and the moves of :func:`beyond` and :func:`turned_free` that use it."""

from __future__ import annotations

import math

import pytest
import torch

from umf.clearance import (
    AROUND,
    BEARINGS,
    beyond,
    crowded,
    formation_end,
    touches,
    turned_free,
)
from umf.reaction_bank import SPOT
from umf.representation import assemble_features, features_to_joints, place_features

pytestmark = pytest.mark.usefixtures("one_thread")


def _moving(x0: float, z0: float, x1: float, z1: float, frames: int = 20) -> torch.Tensor:
    """Features (frames, 262) of a body whose pelvis goes from (x0, z0) to (x1, z1) on the
    floor in a straight line: every joint above the pelvis, a little ahead of it."""
    t = torch.linspace(0.0, 1.0, frames + 1)[:, None]
    joints = torch.zeros(frames + 1, 22, 3)
    joints[..., 1] = torch.linspace(0.0, 1.6, 22)
    joints[..., 0] += x0 + (x1 - x0) * t
    joints[..., 2] += z0 + (z1 - z0) * t + torch.linspace(0.0, 0.3, 22)
    return assemble_features(joints, torch.zeros(frames + 1, 21, 6))


def _bodies(*people: torch.Tensor) -> torch.Tensor:
    """(1, M, T, 22, 3) joints of people as :func:`touches` reads them."""
    return features_to_joints(torch.stack(people))[None]


def test_touches_is_the_closest_joints_over_every_frame():
    """Against brute force on random bodies; a start far apart does not hide a later
    meeting; NaN (nobody) never touches."""
    gen = torch.Generator().manual_seed(0)
    rows = torch.stack([_moving(0, 0, 0, 0), _moving(1.5, 0, 0.1, 0), _moving(1.5, 0, 1.5, 0)])
    other = _moving(0.0, 0.0, 0.0, 0.0) + 0.0
    bodies = _bodies(other).expand(3, -1, -1, -1, -1)
    # row 0 stands on them, row 1 starts 1.5 m away and walks into them, row 2 stays away
    assert touches(rows, bodies, 0.25).tolist() == [True, True, False]
    assert not bool(crowded(rows[1:2], torch.tensor([[[0.0, 0.0]]]))[0])  # the start rule misses it
    nobody = torch.full_like(bodies, float("nan"))
    assert not touches(rows, nobody, 0.25).any()
    # brute force: the smallest joint distance at the same frame, over every frame
    noisy = rows + 0.05 * torch.randn(rows.shape, generator=gen) * (torch.arange(262) < 66)
    a, b = features_to_joints(noisy), bodies[:, 0]
    gap = (a[:, :, :, None] - b[:, :, None]).norm(dim=-1).flatten(1).amin(dim=1)
    for clear in (0.2, float(gap[1]) + 1e-4, float(gap[1]) - 1e-4, 1.0):
        assert touches(noisy, bodies, clear).tolist() == (gap < clear).tolist()


def test_beyond_moves_a_file_walker_off_a_body_it_meets_later():
    """Person 3 of a single file starts 0.9 m behind person 2 (beyond the start rule's
    ``SPOT``) and catches up with them: with the bodies it is moved back by person 2's
    start until it touches nobody; without, it stays. A walker beside person 2 who drifts
    onto them (a row) is not moved by touching alone."""
    person2 = _moving(0.0, -1.2, 0.0, 0.8)
    row = _moving(0.1, -2.1, 0.1, 0.6)[None]  # faster: ends 0.2 m behind person 2
    others = torch.tensor([[[0.0, -1.2]]])
    bodies = _bodies(person2)
    torch.testing.assert_close(beyond(row, others), row)  # the start rule alone: stays
    moved = beyond(row, others, bodies, 0.45)
    assert not bool(touches(moved, bodies, 0.45)[0])
    start = features_to_joints(moved[:, :1])[0, 0, 0, [0, 2]]
    torch.testing.assert_close(start, torch.tensor([0.1, -3.3]), atol=1e-5, rtol=0)
    torch.testing.assert_close(moved[:, :, 66:], row[:, :, 66:])  # only moved on the floor
    torch.testing.assert_close(beyond(row, others, bodies, 0.05), row)  # touching nobody
    beside = _moving(0.9, 0.0, 0.9, 2.0)
    drifting = _moving(1.9, 0.0, 1.0, 2.0)[None]
    assert bool(touches(drifting, _bodies(beside), 0.45)[0])
    same = beyond(drifting, torch.tensor([[[0.9, 0.0]]]), _bodies(beside), 0.45)
    torch.testing.assert_close(same, drifting)


def test_beyond_steps_outwards_where_steps_by_a_start_do_not_clear():
    """A walker still touching someone after the start-sized steps goes on the same way in
    0.25 m steps: one step beyond person 2 it is off their spot (0.9 m, ``SPOT`` 0.8) but
    still within ``clear`` 1.2 of their body, so two more small steps (1.4 m)."""
    person2 = _moving(0.9, 0.0, 0.9, 0.0)
    row = _moving(0.9, 0.0, 0.9, 0.0)[None]  # on person 2's spot
    others = torch.tensor([[[0.9, 0.0]]])
    bodies = _bodies(person2)
    start = beyond(row, others)
    assert float(features_to_joints(start[:, :1])[0, 0, 0, 0]) == pytest.approx(1.8)
    moved = beyond(row, others, bodies, 1.2)
    assert not bool(touches(moved, bodies, 1.2)[0])
    assert float(features_to_joints(moved[:, :1])[0, 0, 0, 0]) == pytest.approx(2.3)


def _bearing(features: torch.Tensor) -> float:
    start = features_to_joints(features[:, :1])[0, 0, 0, [0, 2]]
    return math.degrees(math.atan2(float(start[0]), float(start[1])))


def test_turned_free_turns_a_row_that_touches_only_later():
    """A row starting 2.4 m in front of person 1, well off person 2's start, whose body
    walks onto person 2's later: turned about the origin to the first bearing of
    ``BEARINGS`` that keeps its start ``AROUND`` from everybody's and its whole motion
    ``body_clear`` from their bodies (found here by trying each); without bodies it stays."""
    person2 = _moving(0.05, 1.0, 0.05, 1.0)
    row = _moving(0.0, 2.4, 0.0, 1.0)[None]  # walks towards person 1, through person 2
    others = torch.tensor([[[0.05, 1.0]]])
    bodies = _bodies(person2)
    same, turned = turned_free(row, others)
    assert not bool(turned[0])
    torch.testing.assert_close(same, row)
    out, turned = turned_free(row, others, bodies=bodies, body_clear=0.45)
    assert bool(turned[0]) and not bool(touches(out, bodies, 0.45)[0])
    start = features_to_joints(out[:, :1])[0, 0, 0, [0, 2]]
    assert float(start.norm()) == pytest.approx(2.4, abs=1e-4)  # as far from person 1
    want = next(
        yaw for yaw in BEARINGS
        if not crowded(place_features(row[0], yaw, 0.0, 0.0)[None], others, AROUND)[0]
        and not touches(place_features(row[0], yaw, 0.0, 0.0)[None], bodies, 0.45)[0]
    )  # fmt: skip
    assert _bearing(out) == pytest.approx(_bearing(place_features(row[0], want, 0.0, 0.0)[None]))
    assert abs(math.degrees(want)) > 20.0  # the start rule alone would have stopped at 20


def test_turned_free_falls_back_to_the_start_rule_where_no_bearing_clears():
    """Person 3 stands next to person 1, and the row walks up to person 1: every bearing
    meets person 3. A row on someone's spot (person 2's) takes the smallest bearing the
    start rule allows, as without bodies; a row on nobody's spot stays."""
    person2, person3 = _moving(0.05, 2.45, 0.05, 2.45), _moving(0.0, 0.0, 0.0, 0.0)
    row = _moving(0.0, 2.4, 0.0, 0.1)[None]
    others = torch.tensor([[[0.05, 2.45], [0.0, 0.0]]])
    bodies = _bodies(person2, person3)
    rule, _ = turned_free(row, others)
    out, turned = turned_free(row, others, bodies=bodies, body_clear=0.45)
    assert bool(turned[0])
    torch.testing.assert_close(out, rule)
    # person 2 elsewhere: on nobody's spot, on person 3's body whatever the bearing: stays
    away = torch.tensor([[[3.0, -3.0], [0.0, 0.0]]])
    far = _bodies(_moving(3.0, -3.0, 3.0, -3.0), person3)
    out, turned = turned_free(row, away, bodies=far, body_clear=0.45)
    assert not bool(turned[0])
    torch.testing.assert_close(out, row)


def test_formation_end_goes_on_behind_as_person_2_began():
    """A file goes on backwards by as far as person 2 started behind person 1, from person
    k - 1's start (not person 1's), at least ``SPOT``; a row (person 2 more beside than
    behind), a person 2 ahead, or one not travelling with person 1 begin none."""
    yes = torch.tensor([True])
    file = torch.tensor([[[0.1, 0.0], [-0.4, -2.0], [0.3, -3.9]]])  # people 1..3
    torch.testing.assert_close(formation_end(file, yes), torch.tensor([[0.3, -5.9]]))
    torch.testing.assert_close(formation_end(file[:, :2], yes), torch.tensor([[-0.4, -4.0]]))
    tight = torch.tensor([[[0.0, 0.0], [0.2, -0.5]]])  # at least SPOT: off their spot
    torch.testing.assert_close(formation_end(tight, yes), torch.tensor([[0.2, -0.5 - SPOT]]))
    row = torch.tensor([[[0.0, 0.0], [0.9, -0.3]]])
    ahead = torch.tensor([[[0.0, 0.0], [0.1, 1.5]]])
    for starts in (row, ahead):
        assert torch.isnan(formation_end(starts, yes)).all()
    assert torch.isnan(formation_end(file, torch.tensor([False]))).all()
