"""Protocol metrics on synthetic embeddings with known answers (umf.eval.metrics)."""

import math

import numpy as np
import pytest
from scipy.special import gammaln

from umf.eval import metrics as M


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _psd_sqrt(a: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(a)
    return (v * np.sqrt(np.clip(w, 0, None))) @ v.T


def _closed_form_fid(mu1, s1, mu2, s2) -> float:
    """Independent route: Tr sqrt(S1 S2) = Tr sqrt(S1^1/2 S2 S1^1/2) (symmetric, eigh only)."""
    r = _psd_sqrt(s1)
    cross = np.trace(_psd_sqrt(r @ s2 @ r))
    return float(np.sum((mu1 - mu2) ** 2) + np.trace(s1) + np.trace(s2) - 2 * cross)


def _random_cov(d: int, rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=(d, d))
    return a @ a.T / d + 0.1 * np.eye(d)


def _mean_chi(d: int) -> float:
    """E of a chi variable with d degrees of freedom."""
    return math.sqrt(2) * math.exp(gammaln((d + 1) / 2) - gammaln(d / 2))


# --------------------------------------------------------------------------- FID
def test_fid_of_identical_sets_is_zero():
    x = _rng().normal(size=(500, 16)) * 3 + 1
    assert abs(M.fid(x, x)) < 1e-8
    assert abs(M.fid(x, x[::-1].copy())) < 1e-8  # order does not matter


def test_frechet_distance_diagonal_closed_form():
    mu1, mu2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    a, b = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 1.0])
    expected = 1 + 0 + 4 + ((1 - 2) ** 2 + (2 - 1) ** 2 + (3 - 1) ** 2)  # |dmu|^2 + sum (sa-sb)^2
    got = M.frechet_distance(mu1, np.diag(a), mu2, np.diag(b))
    assert got == pytest.approx(expected, abs=1e-9)


def test_frechet_distance_non_commuting_covariances():
    rng = _rng(1)
    for d in (2, 5, 12):
        s1, s2 = _random_cov(d, rng), _random_cov(d, rng)
        mu1, mu2 = rng.normal(size=d), rng.normal(size=d)
        assert not np.allclose(s1 @ s2, s2 @ s1)  # sqrtm(S1 S2) is not symmetric here
        got = M.frechet_distance(mu1, s1, mu2, s2)
        assert got == pytest.approx(_closed_form_fid(mu1, s1, mu2, s2), rel=1e-7, abs=1e-9)
    # shifting one Gaussian by delta adds exactly |delta|^2
    base = M.frechet_distance(mu1, s1, mu1, s2)
    assert M.frechet_distance(mu1 + 2.0, s1, mu1, s2) == pytest.approx(base + 4.0 * d)


def test_fid_of_sampled_gaussians_matches_closed_form():
    rng = _rng(2)
    d, n = 4, 40_000
    s1, s2 = _random_cov(d, rng), _random_cov(d, rng)
    mu1, mu2 = np.zeros(d), np.full(d, 0.5)
    x = rng.multivariate_normal(mu1, s1, size=n)
    y = rng.multivariate_normal(mu2, s2, size=n)
    expected = _closed_form_fid(mu1, s1, mu2, s2)
    assert expected > 1.0
    assert M.fid(x, y) == pytest.approx(expected, rel=0.05)
    # a pure shift of the same sample: exactly |shift|^2
    assert M.fid(x, x + 0.5) == pytest.approx(0.25 * d, rel=1e-6)


def test_fid_scales_quadratically_and_is_symmetric():
    rng = _rng(3)
    x, y = rng.normal(size=(300, 8)), rng.normal(size=(250, 8)) * 1.5 + 0.3
    assert M.fid(6 * x, 6 * y) == pytest.approx(36 * M.fid(x, y), rel=1e-6)
    assert M.fid(x, y) == pytest.approx(M.fid(y, x), rel=1e-6)


def test_fid_with_singular_covariances_is_finite():
    rng = _rng(4)
    x = np.zeros((100, 6))
    x[:, :2] = rng.normal(size=(100, 2))  # rank 2 in 6-D
    y = x + np.array([1.0, 0, 0, 0, 0, 0])
    assert M.fid(x, y) == pytest.approx(1.0, abs=1e-3)


def test_fid_input_errors():
    with pytest.raises(ValueError):
        M.fid(np.zeros((1, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError):
        M.fid(np.zeros((5, 3)), np.zeros((5, 4)))


# --------------------------------------------------------------------------- R-precision
def test_r_precision_perfect_retrieval_is_one():
    x = _rng().normal(size=(96 * 3, 32))
    assert M.r_precision(x, x.copy()) == (1.0, 1.0, 1.0)
    near = x + 1e-3 * _rng(1).normal(size=x.shape)
    assert M.r_precision(near, x) == (1.0, 1.0, 1.0)


def test_r_precision_of_random_embeddings_is_k_over_group():
    rng = _rng(5)
    n_groups, g = 400, 96
    t, m = rng.normal(size=(n_groups * g, 8)), rng.normal(size=(n_groups * g, 8))
    got = M.r_precision(t, m, group=g, top_k=3)
    for k, value in enumerate(got, start=1):
        p = k / g
        sd = math.sqrt(p * (1 - p) / (n_groups * g))
        assert abs(value - p) < 5 * sd


def test_r_precision_known_ranks_texts_rank_motions():
    """Text 0 is far from its motion (rank 4); motion 0 sits on text 5, pushing it to rank 1.

    Ranking texts for each motion instead would give top-1 95/96, not 94/96.
    """
    g = 96
    t = 10.0 * np.arange(g, dtype=float)[:, None]
    m = t + 3.0
    m[0] = 50.0
    assert M.r_precision(t, m, group=g, top_k=3) == pytest.approx((94 / g, 95 / g, 95 / g))
    assert M.r_precision(m, t, group=g, top_k=3) == pytest.approx((95 / g, 95 / g, 95 / g))
    assert M.r_precision(t, m, group=g, top_k=5) == pytest.approx(
        (94 / g, 95 / g, 95 / g, 95 / g, 1.0)
    )


def test_r_precision_ranks_within_groups_and_drops_the_tail():
    x = _rng(6).normal(size=(96, 16))
    twice = np.concatenate([x, x])  # across groups every motion has an identical twin
    assert M.r_precision(twice, twice) == (1.0, 1.0, 1.0)
    tail = _rng(7).normal(size=(50, 16))  # an incomplete group, all wrong, is ignored
    t = np.concatenate([twice, tail])
    m = np.concatenate([twice, tail[::-1] + 100])
    assert M.r_precision(t, m) == (1.0, 1.0, 1.0)
    with pytest.raises(ValueError):
        M.r_precision(x[:95], x[:95])
    with pytest.raises(ValueError):
        M.r_precision(x, x[:, :8])


# --------------------------------------------------------------------------- MM-Dist
def test_mm_dist_known_value():
    t = np.zeros((10, 3))
    m = np.tile([3.0, 4.0, 0.0], (10, 1))
    assert M.mm_dist(t, m) == pytest.approx(5.0)
    m[5:] = [0.0, 0.0, 1.0]
    assert M.mm_dist(t, m) == pytest.approx(3.0)


def test_euclidean_distances_matches_definition():
    rng = _rng(8)
    a, b = rng.normal(size=(5, 7)), rng.normal(size=(4, 7))
    d = M.euclidean_distances(a, b)
    assert d.shape == (5, 4)
    assert d[2, 3] == pytest.approx(np.sqrt(((a[2] - b[3]) ** 2).sum()))
    assert np.all(np.diag(M.euclidean_distances(a, a)) == 0.0)


# --------------------------------------------------------------------------- Diversity / MModality
def test_diversity_of_isotropic_gaussian():
    """x - y ~ N(0, 2 s^2 I): E||x - y|| = sqrt(2) s E[chi_D]."""
    d, s = 16, 0.7
    emb = _rng(9).normal(size=(20_000, d)) * s + 5.0
    values = [M.diversity(emb, 300, _rng(100 + i)) for i in range(60)]
    expected = math.sqrt(2) * s * _mean_chi(d)
    assert np.mean(values) == pytest.approx(expected, rel=0.01)


def test_diversity_edge_cases():
    assert M.diversity(np.ones((400, 4)), 300, _rng()) == 0.0
    emb = np.array([[0.0], [1.0]])  # two points: the draws coincide or are swapped
    vals = [M.diversity(emb, 2, _rng(i)) for i in range(400)]
    assert set(np.round(vals, 9)) <= {0.0, 1.0}
    assert np.mean(vals) == pytest.approx(0.5, abs=0.08)
    with pytest.raises(ValueError):
        M.diversity(np.zeros((299, 4)), 300, _rng())
    a = M.diversity(_rng(1).normal(size=(500, 4)), 300, _rng(3))
    b = M.diversity(_rng(1).normal(size=(500, 4)), 300, _rng(3))
    assert a == b  # seeded


def test_multimodality_is_within_prompt_only():
    d, s = 8, 0.3
    rng = _rng(10)
    prompts, samples = 200, 30
    centres = 1000.0 * rng.normal(size=(prompts, 1, d))
    emb = centres + s * rng.normal(size=(prompts, samples, d))
    got = np.mean([M.multimodality(emb, 10, _rng(i)) for i in range(20)])
    # the two index draws coincide with probability 1/S, giving distance 0
    expected = (1 - 1 / samples) * math.sqrt(2) * s * _mean_chi(d)
    assert got == pytest.approx(expected, rel=0.015)
    same = np.repeat(rng.normal(size=(5, 1, d)), samples, axis=1)
    assert M.multimodality(same, 10, _rng()) == 0.0
    with pytest.raises(ValueError):
        M.multimodality(emb[:, :9], 10, _rng())
    with pytest.raises(ValueError):
        M.multimodality(emb[0], 10, _rng())


# --------------------------------------------------------------------------- summary
def test_mean_ci_uses_population_std():
    mean, half = M.mean_ci([1.0, 2.0, 3.0, 4.0])
    assert mean == pytest.approx(2.5)
    assert half == pytest.approx(1.96 * math.sqrt(1.25) / 2)  # ddof=0: sqrt(1.25), not sqrt(5/3)
    means, halves = M.mean_ci(np.array([[1.0, 10.0], [3.0, 10.0]]))
    assert means.tolist() == [2.0, 10.0]
    assert halves == pytest.approx([1.96 * 1.0 / math.sqrt(2), 0.0])
    assert M.mean_ci([7.0]) == (7.0, 0.0)
    with pytest.raises(ValueError):
        M.mean_ci([])


def test_retrieval_ceiling():
    assert M.retrieval_ceiling(range(192)) == (1.0, 1.0, 1.0)
    assert M.retrieval_ceiling(["same"] * 96) == pytest.approx((1 / 96, 2 / 96, 3 / 96))
    # 48 pairs of twins per group: top-1 1/2, top-2 and top-3 1; the 10-item tail is ignored
    keys = [i // 2 for i in range(96)] + ["x"] * 10
    assert M.retrieval_ceiling(keys) == pytest.approx((0.5, 1.0, 1.0))
    mixed = ["a"] * 4 + list(range(4))  # group of 8: four interchangeable items, four unique
    assert M.retrieval_ceiling(mixed, group=8) == pytest.approx((5 / 8, 6 / 8, 7 / 8))
    with pytest.raises(ValueError):
        M.retrieval_ceiling(range(10))
