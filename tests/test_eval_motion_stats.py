"""Per-label body statistics (umf.eval.motion_stats) on motions built by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from umf.eval import motion_stats as MS
from umf.skeleton import NUM_JOINTS, PARENTS, default_offsets

FPS = 30.0


def rest_pose() -> np.ndarray:
    """Standing rest pose (22, 3), facing +Z, feet on the floor."""
    off = default_offsets().numpy().astype(np.float64)
    pos = np.zeros((NUM_JOINTS, 3))
    for j in range(1, NUM_JOINTS):
        pos[j] = pos[PARENTS[j]] + off[j]
    pos[:, 1] -= pos[:, 1].min()
    return pos


def still(frames: int = 120) -> np.ndarray:
    return np.repeat(rest_pose()[None], frames, axis=0)


def test_rest_pose_faces_plus_z():
    from umf.representation import facing_direction

    f = facing_direction(torch.from_numpy(rest_pose()[None]))[0].numpy()
    np.testing.assert_allclose(f, [0, 0, 1], atol=1e-6)


def test_pelvis_speed_and_direction():
    t = np.arange(120) / FPS
    fwd, back = still(), still()
    fwd[..., 2] += 1.2 * t[:, None]  # 1.2 m/s along the facing direction
    back[..., 2] -= 0.8 * t[:, None]
    s_fwd, s_back = MS.motion_statistics(fwd), MS.motion_statistics(back)
    assert abs(s_fwd["pelvis_speed"] - 1.2) < 1e-6
    assert abs(s_fwd["backward_speed"] + 1.2) < 1e-6  # forward travel is negative backward
    assert abs(s_back["backward_speed"] - 0.8) < 1e-6
    # travel alone is not gesture: root-relative energies stay zero
    assert s_fwd["wrist_energy"] < 1e-9 and s_fwd["ankle_energy"] < 1e-9


def test_head_drop_and_wrists():
    bow = still()
    drop = np.zeros(120)
    drop[20:] = 0.2 * np.sin(np.linspace(0, np.pi, 100))  # stands, down 20 cm and back up
    bow[:, MS.HEAD, 1] -= drop
    assert abs(MS.motion_statistics(bow)["head_drop"] - 0.2) < 1e-3
    wave = still()
    head_y = wave[0, MS.HEAD, 1]
    wave[:, MS.R_WRIST, 1] = head_y + 0.3  # held 30 cm above the head
    wave[:, MS.R_WRIST, 0] += 0.1 * np.sin(2 * np.pi * 2.5 * np.arange(120) / FPS)  # 2.5 Hz
    s = MS.motion_statistics(wave)
    assert abs(s["right_wrist_above_head"] - 0.3) < 1e-9
    # mean |d/dt 0.1 sin(5 pi t)| = 0.1 * 5 pi * 2 / pi = 1.0 m/s
    assert abs(s["right_wrist_energy"] - 1.0) < 0.02
    assert s["both_wrists_above_head"] < 0  # the left hand stays down


def test_a_still_pose_fails_a_wave_and_a_wave_passes():
    rng = np.random.default_rng(0)
    real = []
    for _ in range(12):
        w = still()
        amp = rng.uniform(0.08, 0.12)
        w[:, MS.R_WRIST, 1] = w[0, MS.HEAD, 1] + rng.uniform(0.25, 0.35)
        w[:, MS.R_WRIST, 0] += amp * np.sin(2 * np.pi * 2.5 * np.arange(120) / FPS)
        real.append(w)
    rows = MS.compare_label("wave-right-hand", real, [still()] * 4)
    assert not all(r.passed for r in rows)
    assert {r.real_count for r in rows} == {12}
    rows = MS.compare_label("wave-right-hand", real, real[:6])
    assert all(r.passed for r in rows)
    assert MS.few_real_clips(rows) == {}


def test_swings_count_turns_of_at_least_ten_centimetres():
    t = np.arange(121) / FPS  # 4 s
    wave = 0.2 * np.sin(2 * np.pi * 1.0 * t)  # 40 cm side to side, once a second
    assert MS.swings_per_second(wave) == pytest.approx(8 / 4)  # turns at 0.25, 0.75 ... 3.75 s
    assert MS.swings_per_second(0.2 * np.sin(2 * np.pi * 2.0 * t)) == pytest.approx(16 / 4)
    assert MS.swings_per_second(0.04 * np.sin(2 * np.pi * 1.0 * t)) == 0  # an 8 cm wobble
    assert MS.swings_per_second(0.5 * t) == 0  # a one-way drift turns nowhere
    noise = np.random.default_rng(0).normal(0, 0.01, 121)
    assert MS.swings_per_second(noise) == 0  # a 1 cm tremor
    assert MS.swings_per_second(wave + noise) == pytest.approx(8 / 4)
    assert MS.swings_per_second(np.r_[0.0, 0.3, 0.0, 0.3, 0.0], fps=1.0) == pytest.approx(3 / 4)


def test_sideways_is_across_the_facing_direction():
    w = still()
    w[:, MS.R_WRIST, 0] += 0.2 * np.sin(np.arange(120) / 5)  # faces +Z: X is sideways
    y = MS.sideways(w)
    np.testing.assert_allclose(y - y[0], w[:, MS.R_WRIST, 0] - w[0, MS.R_WRIST, 0], atol=1e-9)
    fwd = still()
    fwd[:, MS.R_WRIST, 2] += 0.2 * np.sin(np.arange(120) / 5)  # forward-back: not sideways
    assert np.ptp(MS.sideways(fwd)) < 1e-9
    turned = w @ np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])  # the same wave, facing +X
    np.testing.assert_allclose(np.abs(MS.sideways(turned) - MS.sideways(turned)[0]),
                               np.abs(y - y[0]), atol=1e-6)  # fmt: skip


def test_a_raised_hand_that_wobbles_is_not_a_wave():
    """It moves as fast as a slow real wave but never swings 10 cm: the swings fail it."""
    rng = np.random.default_rng(0)
    t = np.arange(120) / FPS
    real = []
    for _ in range(12):
        w = still()
        w[:, MS.R_WRIST, 1] = w[0, MS.HEAD, 1] + 0.3
        w[:, MS.R_WRIST, 0] += rng.uniform(0.1, 0.2) * np.sin(2 * np.pi * rng.uniform(0.8, 1.6) * t)
        real.append(w)
    wobble = still()
    wobble[:, MS.R_WRIST, 1] = wobble[0, MS.HEAD, 1] + 0.3
    wobble[:, MS.R_WRIST, 0] += 0.04 * np.sin(2 * np.pi * 4.0 * t)  # fast, 8 cm
    rows = {r.stat: r for r in MS.compare_label("wave-right-hand", real, [wobble] * 4)}
    assert rows["right_wrist_energy"].passed and rows["right_wrist_above_head"].passed
    assert not rows["right_wrist_swings"].passed
    assert all(r.passed for r in MS.compare_label("wave-right-hand", real, real[:6]))


def test_labels_with_few_real_clips_are_named_and_shown():
    rows = MS.compare_label("kick", [still()], [still()])
    assert MS.few_real_clips(rows) == {"kick": 1}
    q = rows[0].real_q
    assert q[0] == q[1] == q[2]  # one clip: a zero-width range
    table = MS.format_checks(rows)
    assert "| real clips |" in table.splitlines()[0]
    assert "| kick | A person kicks. | ankle_energy | 1 |" in table
    # zero width: a second, slightly different kick fails although it is a kick too
    other = still()
    other[:, MS.R_ANKLE, 1] += 0.05 * np.sin(np.linspace(0, np.pi, 120))
    assert MS.label_passes(MS.compare_label("kick", [still()], [other])) == {"kick": False}


def test_backward_is_measured_against_the_facing_direction():
    """A person facing +X who travels along -X walks backward; along +Z, sideways."""
    turned = rest_pose()[:, [2, 1, 0]] * np.array([1.0, 1.0, -1.0])  # 90 degrees about Y
    from umf.representation import facing_direction

    f = facing_direction(torch.from_numpy(turned[None]))[0].numpy()
    np.testing.assert_allclose(f, [1, 0, 0], atol=1e-6)
    t = np.arange(120) / FPS
    back = np.repeat(turned[None], 120, axis=0)
    back[..., 0] -= 0.7 * t[:, None]
    side = np.repeat(turned[None], 120, axis=0)
    side[..., 2] += 0.7 * t[:, None]
    assert abs(MS.motion_statistics(back)["backward_speed"] - 0.7) < 1e-6
    assert abs(MS.motion_statistics(side)["backward_speed"]) < 1e-6
    assert abs(MS.motion_statistics(side)["pelvis_speed"] - 0.7) < 1e-6


def test_pelvis_speed_is_path_length_not_displacement():
    """Walking out and back covers distance although it ends where it started."""
    t = np.arange(121) / FPS
    x = np.where(t <= 2.0, t, 4.0 - t)  # 1 m/s out for 2 s, then back
    walk = still(121)
    walk[..., 2] += x[:, None]
    assert abs(MS.motion_statistics(walk)["pelvis_speed"] - 1.0) < 1e-6


def test_median_statistics_is_the_median_person(real_joints):
    walk = real_joints[:90].numpy()
    fast = walk[::2].copy()  # every other frame: the same walk at twice the speed
    people = [walk, fast, walk]
    names = ("pelvis_speed", "head_drop")
    med = MS.median_statistics(people, names)
    each = [MS.motion_statistics(j) for j in people]
    assert med == [float(np.median([e[n] for e in each])) for n in names]
    pelvis = MS.motion_statistics(walk)["pelvis_speed"]
    assert med[0] == pelvis and MS.motion_statistics(fast)["pelvis_speed"] > 1.5 * pelvis
