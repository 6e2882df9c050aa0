"""The body-frame view of a motion: exact round trip, placement invariance, statistics."""

from __future__ import annotations

import math

import pytest
import torch

from conftest import MODULE
from umf.body_frame import (
    BODY_DIM,
    HEADING,
    LOCAL_POS,
    ROOT,
    TRAJECTORY,
    fit_body_normalizer,
    from_body_frame,
    to_body_frame,
)
from umf.representation import joints_to_features, place_features


@pytest.fixture(scope=MODULE)
def walk(real_joints):
    return joints_to_features(real_joints)  # (T - 1, 262) float64, canonical


def test_round_trip_is_exact(walk):
    placed = place_features(walk, 2.1, -1.3, 0.8)
    body = to_body_frame(placed)
    assert body.shape == (*walk.shape[:-1], BODY_DIM)
    assert torch.allclose(from_body_frame(body), placed, atol=1e-9)
    # batched (P, T, 262) scenes too
    scene = torch.stack([walk, placed])
    assert torch.allclose(from_body_frame(to_body_frame(scene)), scene, atol=1e-9)


@pytest.mark.parametrize("yaw", [-2.5, -0.4, 0.9, 3.0])
def test_pose_slots_ignore_placement(walk, yaw):
    """Turning and moving a person changes only the four trajectory numbers."""
    a, b = to_body_frame(walk), to_body_frame(place_features(walk, yaw, 1.7, -2.2))
    assert torch.allclose(a[:, TRAJECTORY.stop :], b[:, TRAJECTORY.stop :], atol=1e-9)
    assert not torch.allclose(a[:, TRAJECTORY], b[:, TRAJECTORY], atol=1e-3)
    # the heading turns by exactly the yaw
    ha = torch.atan2(a[:, HEADING][:, 0], a[:, HEADING][:, 1])
    hb = torch.atan2(b[:, HEADING][:, 0], b[:, HEADING][:, 1])
    diff = torch.remainder(hb - ha + math.pi, 2 * math.pi) - math.pi
    assert torch.allclose(diff, torch.full_like(diff, yaw), atol=1e-6)


def test_local_positions_are_the_pose(walk):
    """Pelvis at x = z = 0 with its height; the head stays above it, facing +Z."""
    local = to_body_frame(walk)[:, LOCAL_POS].reshape(-1, 22, 3)
    assert torch.allclose(local[:, 0, [0, 2]], torch.zeros_like(local[:, 0, [0, 2]]), atol=1e-9)
    assert torch.allclose(local[:, 0, 1], walk[:, 1])  # pelvis height kept
    assert (local[:, 15, 1] > local[:, 0, 1] + 0.3).all()
    # in the heading frame the left hip is on +X (a person facing +Z has their left at +X)
    assert (local[:, 1, 0] > 0).float().mean() > 0.95


def test_heading_of_any_length_decodes(walk):
    """A decoder's (sin, cos) need not be unit length: scaling it changes nothing."""
    body = to_body_frame(walk)
    scaled = body.clone()
    scaled[:, HEADING] *= 3.7
    assert torch.allclose(from_body_frame(scaled), from_body_frame(body), atol=1e-9)


def test_normalizer_covers_the_placement(walk):
    plain = fit_body_normalizer(walk)
    placed = fit_body_normalizer(walk, placement_radius=3.0)
    assert torch.allclose(plain.std[LOCAL_POS], placed.std[LOCAL_POS])  # pose: no change
    assert (placed.std[ROOT] > math.sqrt(3.0) - 1e-6).all()  # uniform(-3, 3): var 3
    assert torch.allclose(placed.std[HEADING].double(), torch.full((2,), math.sqrt(0.5)).double())
    assert torch.equal(placed.mean[TRAJECTORY], torch.zeros(4))
    # contacts stay 0/1 labels
    assert torch.equal(placed.mean[-4:], torch.zeros(4))
    assert torch.equal(placed.std[-4:], torch.ones(4))


def test_normalizer_defaults_are_the_plain_statistics(walk):
    """No placement by default: the trajectory keeps the corpus's own mean and spread, and
    std is floored at min_std = 1e-2 only (pose slots of a few centimetres stay as they are)."""
    norm = fit_body_normalizer(walk)
    body = to_body_frame(walk)
    assert torch.allclose(norm.mean[:-4], body.mean(0)[:-4].float())
    assert torch.allclose(norm.std[:-4], body.std(0).clamp_min(1e-2)[:-4].float())
    assert norm.mean[HEADING][1] > 0.99  # the walk faces +Z throughout: cos(yaw) near 1
    assert (norm.std[LOCAL_POS] < 0.5).any()  # small pose spreads are not floored up
    assert (norm.std[:-4] == torch.tensor(1e-2)).any()  # e.g. the pelvis's local x and z


def test_normalizer_accepts_any_leading_shape(walk):
    scene = torch.stack([walk, place_features(walk, 1.0, 2.0, -0.5)])
    a = fit_body_normalizer(scene, placement_radius=1.5)
    b = fit_body_normalizer(scene.reshape(-1, scene.shape[-1]), placement_radius=1.5)
    assert torch.equal(a.mean, b.mean) and torch.equal(a.std, b.std)


@pytest.mark.parametrize("radius", [0.5, 3.0])
def test_normalizer_root_spread_formula(walk, radius):
    """Root x/z std = sqrt((mean canonical x^2 + z^2) / 2 + radius^2 / 3), any radius > 0."""
    norm = fit_body_normalizer(walk, placement_radius=radius)
    root = to_body_frame(walk)[:, ROOT]
    spread = float((root[:, 0] ** 2 + root[:, 1] ** 2).mean()) / 2
    want = math.sqrt(spread + radius**2 / 3)
    assert torch.allclose(norm.std[ROOT].double(), torch.full((2,), want).double(), rtol=1e-6)
    assert torch.equal(norm.mean[TRAJECTORY], torch.zeros(4))
