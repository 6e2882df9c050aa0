import numpy as np
import pytest
import torch

from umf.data.composer import compose_corpus
from umf.data.scenes import build_scene
from umf.eval import physics as P

FPS = 30.0


@pytest.fixture(scope="module")
def pose(actors):
    """A real standing pose on the floor (22, 3), float64: ankles 7.5 cm up, toes on it."""
    bow = next(a for a in actors if a.id == "dataset-1_bow_normal_001")
    return bow.joints[0].astype(np.float64)


def _shift(x, dx=0.0, dy=0.0, dz=0.0):
    return x + np.array([dx, dy, dz])


def _point_segment(x, p, q):
    d = q - p
    n = d @ d
    t = np.zeros(len(x)) if n < 1e-15 else np.clip((x - p) @ d / n, 0, 1)
    return np.linalg.norm(p + t[:, None] * d - x, axis=-1)


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(0)
    s = np.linspace(0, 1, 20001)[:, None]
    for i in range(250):
        p1, q1, p2, q2 = rng.normal(size=(4, 3))
        kind = i % 6
        if kind == 1:  # parallel
            q2 = p2 + (q1 - p1) * rng.uniform(-2, 2)
        elif kind == 2:  # collinear, overlapping or not
            p2 = p1 + (q1 - p1) * rng.uniform(-1, 1)
            q2 = p1 + (q1 - p1) * rng.uniform(-1, 2)
        elif kind == 3:  # a point against a segment
            q1 = p1.copy()
        elif kind == 4:  # two points
            q1, q2 = p1.copy(), p2.copy()
        elif kind == 5:  # crossing segments
            mid = (p1 + q1) / 2
            p2, q2 = mid - (q2 - p2), mid + (q2 - p2)
        brute = _point_segment(p1 + s * (q1 - p1), p2, q2).min()
        assert P.segment_distance(p1, q1, p2, q2) == pytest.approx(brute, abs=1e-6)
        assert P.segment_distance(p2, q2, p1, q1) == pytest.approx(brute, abs=1e-6)
    # broadcasting over leading axes
    a = rng.normal(size=(5, 1, 2, 3))
    b = rng.normal(size=(1, 7, 2, 3))
    d = P.segment_distance(a[..., 0, :], a[..., 1, :], b[..., 0, :], b[..., 1, :])
    assert d.shape == (5, 7)
    assert d[3, 4] == pytest.approx(
        P.segment_distance(a[3, 0, 0], a[3, 0, 1], b[0, 4, 0], b[0, 4, 1])
    )


def test_radii_cover_every_bone():
    r = P.bone_radii()
    assert r.shape == (21,) and (r > 0.02).all() and (r < 0.15).all()


def test_point_people_known_penetration():
    # every joint on one point: 21 spheres, the largest (torso) 0.11 m, so two such
    # "people" d apart overlap by 0.22 - d
    t = 40
    a = np.zeros((t, 22, 3))
    b = np.zeros((t, 22, 3))
    b[:20, :, 0] = 0.15  # 7 cm overlap for half the frames
    b[20:, :, 0] = 1.00  # apart for the rest
    depth = P.capsule_penetration(a, b)
    assert depth[:20] == pytest.approx(0.07)
    assert (depth[20:] == 0).all()
    per = P.interpenetration(np.stack([a, b]))
    for p in per:
        assert p["penetration_cm"] == pytest.approx(3.5)
        assert p["penetration_frac"] == 0.5
        assert p["penetration_max_cm"] == pytest.approx(7.0)


def test_capsules_of_real_people(pose):
    """Exact against an uncropped 21 x 21 computation; zero far apart."""
    walk = np.stack([_shift(pose, dz=0.02 * k) for k in range(30)])
    other = walk.copy()
    other[..., 0] += np.linspace(2.0, 0.1, 30)[:, None]  # comes in from the side
    pa, qa = walk[:, P._BONE_PARENTS], walk[:, P._BONE_CHILDREN]
    pb, qb = other[:, P._BONE_PARENTS], other[:, P._BONE_CHILDREN]
    dist = P.segment_distance(pa[:, :, None], qa[:, :, None], pb[:, None], qb[:, None])
    r = P.bone_radii()
    brute = np.clip((r[:, None] + r[None] - dist).reshape(30, -1).max(-1), 0, None)
    got = P.capsule_penetration(walk, other)
    np.testing.assert_allclose(got, brute, atol=1e-12)
    assert got[0] == 0.0 and got[-1] > 0.1  # 10 cm apart: deep overlap
    m = P.penetration_matrix(np.stack([walk, other, _shift(walk, 5.0)]))
    assert m.shape == (3, 3, 30)
    np.testing.assert_allclose(m, m.transpose(1, 0, 2))
    assert (m[0, 2] == 0).all() and (m[np.arange(3), np.arange(3)] == 0).all()
    prev = P.penetration_with_previous(np.stack([walk, other, _shift(walk, 5.0)]))
    assert prev[0]["penetration_cm"] == 0.0 and prev[2]["penetration_cm"] == 0.0
    assert prev[1]["penetration_cm"] == pytest.approx(100 * got.mean())


def test_sliding_foot_skates(pose):
    t, speed = 60, 0.8
    slide = np.stack([_shift(pose, speed * k / FPS) for k in range(t)])
    s = P.foot_skating(slide, FPS)
    assert s["skate_ratio"] == 1.0 and s["grounded_frac"] == 1.0
    assert s["skate_speed"] == pytest.approx(speed)
    assert s["grounded_speed"] == pytest.approx(speed)
    slow = np.stack([_shift(pose, 0.3 * k / FPS) for k in range(t)])
    s = P.foot_skating(slow, FPS)
    assert s["skate_ratio"] == 0.0 and s["grounded_speed"] == pytest.approx(0.3)
    still = P.foot_skating(np.repeat(pose[None], t, 0), FPS)
    assert still == {"skate_ratio": 0.0, "skate_speed": 0.0, "grounded_speed": 0.0,
                     "grounded_frac": 1.0}  # fmt: skip
    # sliding 10 cm above the floor is floating, not skating
    assert P.foot_skating(_shift(slide, dy=0.1), FPS)["grounded_frac"] == 0.0


def test_floating_and_ground_penetration(pose):
    still = np.repeat(pose[None], 20, 0)
    base = pose[list(P.FOOT_JOINTS), 1].min()
    assert P.floating(still) == {"float_ratio": 0.0, "float_height_cm": pytest.approx(100 * base)}
    lifted = P.floating(_shift(still, dy=0.10))
    assert lifted["float_ratio"] == 1.0
    assert lifted["float_height_cm"] == pytest.approx(100 * (base + 0.10))
    assert P.ground_penetration(still)["ground_pen_cm"] == 0.0
    sunk = still.copy()
    sunk[10:, :, 1] -= 0.05
    g = P.ground_penetration(sunk)
    depth = 0.05 - pose[:, 1].min()
    assert g["ground_pen_cm"] == pytest.approx(100 * depth / 2)
    assert g["ground_pen_ratio"] == 0.5
    assert g["ground_pen_max_cm"] == pytest.approx(100 * depth)


def test_jitter(pose):
    still = P.jitter(np.repeat(pose[None], 20, 0), FPS)
    assert still == {"accel": 0.0, "jerk": 0.0}
    amp, freq = 0.1, 0.5  # every joint moves 10 cm along x at 0.5 Hz, 4 whole periods
    t = np.arange(int(4 / freq * FPS) + 1) / FPS
    w = 2 * np.pi * freq
    x = amp * np.sin(w * t)
    moving = np.repeat(pose[None], len(t), 0)
    moving[..., 0] += x[:, None]
    j = P.jitter(moving, FPS)
    # second difference of a sampled sinusoid: exactly -(2 sin(w h / 2) / h)^2 x
    factor = (2 * np.sin(w / FPS / 2) * FPS) ** 2
    assert j["accel"] == pytest.approx(factor * np.abs(x[1:-1]).mean(), rel=1e-9)
    assert j["accel"] == pytest.approx(amp * w**2 * 2 / np.pi, rel=1e-2)  # continuous mean
    assert j["jerk"] == pytest.approx(amp * w**3 * 2 / np.pi, rel=1e-2)
    assert np.isnan(P.jitter(moving[:3], FPS)["jerk"])


def test_report_accepts_torch_and_aggregates(pose):
    scene = np.stack([np.repeat(pose[None], 10, 0), _shift(np.repeat(pose[None], 10, 0), 0.15)])
    rep = P.physics_report(torch.from_numpy(scene))
    assert len(rep["per_person"]) == 2
    for key, value in rep.items():
        if key not in ("per_person", "penetration_max_cm"):
            assert value == pytest.approx(np.mean([p[key] for p in rep["per_person"]]))
    assert rep["penetration_cm"] > 5  # two bodies 15 cm apart
    avg = P.average_reports([rep, P.physics_report(scene[:1])])
    assert "per_person" not in avg
    assert avg["penetration_cm"] == pytest.approx(rep["penetration_cm"] / 2)
    with pytest.raises(ValueError):
        P.physics_report(scene[0])


def test_real_motion_is_plausible(actors):
    """Real Bandai motion (the bundled clips, canonical: lowest joint on the floor).

    Measured here: skate ratio 0 for standing gestures, 0.03 for the kick, 0-0.11 for
    walking, 0.16 for walking while turning and 0.14 for the run; grounded foot speed
    <= 0.3 m/s; floating only in the run's flight phases (40 % of its frames); no joint
    under the floor; jerk 4-15 m/s^3 for gestures, 50-240 walking, 540 running.
    """
    reports = {a.id: P.person_physics(a.joints, FPS) for a in actors}
    for cid, r in reports.items():
        assert r["ground_pen_cm"] == 0.0, cid
        running = "run" in cid
        assert r["skate_ratio"] <= 0.2, (cid, r)
        assert r["grounded_speed"] <= 0.35, (cid, r)
        assert r["float_ratio"] <= (0.5 if running else 0.0), (cid, r)
        assert r["jerk"] < (700 if running else 300), (cid, r)
        if not any(w in cid for w in ("walk", "run", "kick")):
            assert r["skate_ratio"] == 0.0 and r["jerk"] < 20, (cid, r)
    assert np.mean([r["skate_ratio"] for r in reports.values()]) < 0.1
    # composed real scenes keep people > 25 cm apart: no capsule overlap either
    by_id = {a.id: a for a in actors}
    recipes = compose_corpus(actors, 12, (2,), seed=5) + compose_corpus(actors, 4, (3, 4, 5, 6), 1)
    for r in recipes:
        rep = P.physics_report(build_scene(r, by_id), FPS)
        assert rep["penetration_max_cm"] == 0.0, r["id"]
        assert rep["ground_pen_cm"] == 0.0 and rep["skate_ratio"] <= 0.2, r["id"]
