"""The pure pieces of the adaptive loop: sampling distribution, selection, stopping (the error metrics:
tests/fe_core/test_frf_data.py)."""

from __future__ import annotations

import numpy as np
import pytest

from strategies import table2


def test_distribution_is_fitted_on_the_best_z_samples(rng):
    X = rng.normal(size=(40, 3))
    errors = rng.uniform(size=40)
    dist = table2.fit_distribution(X, errors, z=10)
    best = X[np.argsort(errors)[:10]]
    np.testing.assert_allclose(dist.mean, best.mean(axis=0))
    np.testing.assert_allclose(dist.std, best.std(axis=0, ddof=1))


def test_distribution_std_has_a_floor():
    X = np.tile([0.1, 0.2], (5, 1))
    dist = table2.fit_distribution(X, np.arange(5.0), z=5, std_floor=1e-3)
    np.testing.assert_allclose(dist.std, 1e-3)


def test_candidates_never_leave_the_valid_domain(rng):
    dist = table2.SamplingDistribution(mean=np.array([-0.98, 0.0, 0.95]), std=np.array([0.2, 0.1, 0.2]))
    C = table2.draw_candidates(dist, 20000, np.full(3, -1.0), np.full(3, 1.0), rng)
    assert C.shape == (20000, 3)
    assert np.all(C > -1.0) and np.all(C <= 1.0)
    # Away from the bounds the draws keep the distribution's moments.
    assert C[:, 1].mean() == pytest.approx(0.0, abs=0.005)
    assert C[:, 1].std() == pytest.approx(0.1, rel=0.03)


def test_uniform_samples_cover_the_box_and_exclude_minus_one(rng):
    X = table2.uniform_samples(5000, np.full(6, -1.0), np.full(6, 1.0), rng)
    assert np.all(X > -1.0) and np.all(X <= 1.0)
    np.testing.assert_allclose(X.mean(axis=0), 0.0, atol=0.05)


def test_a_distribution_outside_the_box_is_reported(rng):
    dist = table2.SamplingDistribution(mean=np.array([5.0]), std=np.array([1e-3]))
    with pytest.raises(ValueError, match="outside"):
        table2.draw_candidates(dist, 10, np.array([-1.0]), np.array([1.0]), rng)


def test_selection_takes_best_scores_at_least_min_distance_apart(rng):
    C = rng.uniform(-1, 1, (2000, 2))
    scores = np.sum(C**2, axis=1)  # best near the origin, where candidates crowd
    chosen = table2.select_diverse(C, scores, 10, 0.2)
    assert len(chosen) == 10
    assert chosen[0] == np.argmin(scores)
    X = C[chosen]
    d = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    assert d[np.triu_indices(10, 1)].min() >= 0.2
    # Without the constraint the ten best all sit within a small disc.
    assert np.sort(scores)[9] < scores[chosen].max()


def test_selection_skips_points_near_evaluated_samples_and_nan_scores(rng):
    C = np.array([[0.0, 0.0], [0.01, 0.0], [0.5, 0.5], [0.9, 0.9]])
    scores = np.array([0.0, 0.1, np.nan, 0.3])
    evaluated = np.array([[0.0, 0.005]])
    # 0 and 1 lie within 0.1 of the evaluated sample and 2 has no score: only 3 qualifies.
    assert list(table2.select_diverse(C, scores, 1, 0.1, exclude=evaluated)) == [3]
    # Asking for two relaxes the distance until 1 (0.011 away) qualifies, never 0 (0.005 away) first.
    assert list(table2.select_diverse(C, scores, 2, 0.1, exclude=evaluated)) == [1, 3]
    chosen = table2.select_diverse(C, scores, 4, 0.1, exclude=evaluated)
    assert 2 not in chosen and len(chosen) == 3


def test_selection_relaxes_the_distance_when_the_pool_is_too_tight():
    C = np.array([[0.0], [0.01], [0.02]])
    chosen = table2.select_diverse(C, np.array([0.0, 1.0, 2.0]), 3, 1.0)
    assert sorted(chosen) == [0, 1, 2]


@pytest.mark.parametrize(
    ("best", "iteration", "fe", "stop", "converged"),
    [
        (0.009, 3, 60, True, True),
        (0.02, 12, 240, True, False),
        (0.02, 5, 230, True, False),
        (0.02, 5, 100, False, False),
    ],
)
def test_stopping_rule(best, iteration, fe, stop, converged):
    d = table2.stopping_rule(best, 0.01, iteration, 12, fe, 240, 20)
    assert (d.stop, d.converged) == (stop, converged)


def test_default_min_distance_scales_with_the_spread():
    wide = table2.SamplingDistribution(np.zeros(6), np.full(6, 0.2))
    narrow = table2.SamplingDistribution(np.zeros(6), np.full(6, 0.02))
    lo, hi = np.full(6, -1.0), np.full(6, 1.0)
    assert table2.default_min_distance(wide, lo, hi) == pytest.approx(10 * table2.default_min_distance(narrow, lo, hi))
    uniform = table2.default_min_distance(None, lo, hi)
    assert uniform == pytest.approx(0.1 * np.sqrt(6 * (2 / np.sqrt(12)) ** 2))
