"""The linearity check and the importance-sampled posterior (fe_core.inference.posterior) on problems with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from fe_core.inference.laplace import laplace_intervals
from fe_core.inference.posterior import importance_posterior, linearity_check


def _linear(rng, m=3, n=40, sigma=0.01):
    A = rng.normal(size=(n, m))
    truth = np.array([0.1, -0.2, 0.3])[:m]
    b = A @ truth + sigma * rng.normal(size=n)
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    return (lambda t: A @ t - b), A, x, sigma


def test_a_linear_model_passes_the_check_and_sampling_reproduces_the_laplace_intervals(rng):
    residual, A, x, sigma = _linear(rng)
    iv = laplace_intervals(residual(x), A, x, noise=sigma, width_threshold=1e-6)  # every parameter "unpinned"
    check = linearity_check(residual, iv, residual(x), -1.0, 1.0)
    assert check.checked.all() and check.fe_runs == 6
    np.testing.assert_allclose(check.ratio, 1.0, rtol=1e-9)  # exactly quadratic
    assert not check.poor.any() and check.reasons() == []
    post = importance_posterior(residual, iv, -1.0, 1.0, rng, budget=2000)
    assert post.ess > 1000  # the proposal is close to the target
    # Monte Carlo error of a 2.5 % quantile with ~1000 effective samples: ~0.1 std
    np.testing.assert_allclose(post.low, iv.low, atol=0.15 * iv.std.max())
    np.testing.assert_allclose(post.high, iv.high, atol=0.15 * iv.std.max())
    np.testing.assert_allclose(post.covariance, iv.covariance, atol=0.1 * iv.std.max() ** 2)


def test_a_bound_through_the_interval_cuts_the_sampled_posterior_as_a_truncated_normal(rng):
    """1-D: r = (t - 0.95) / 1 with noise 0.05: the posterior is N(0.95, 0.05^2) cut at 1."""
    residual = lambda t: np.atleast_1d(t[0] - 0.95)  # noqa: E731
    iv = laplace_intervals(np.zeros(1), np.ones((1, 1)), [0.95], noise=0.05, upper=1.0)
    assert iv.near_bound[0]
    check = linearity_check(residual, iv, np.zeros(1), -1.0, 1.0)
    assert check.poor[0] and check.outside[0, 1] and "crosses a bound" in check.reasons()[0]
    post = importance_posterior(residual, iv, -1.0, 1.0, rng, budget=4000)
    cut = stats.truncnorm(-np.inf, (1.0 - 0.95) / 0.05, loc=0.95, scale=0.05)
    assert post.high[0] <= 1.0 and post.high[0] == pytest.approx(cut.ppf(0.975), abs=0.01)
    assert post.low[0] == pytest.approx(cut.ppf(0.025), abs=0.01)
    assert post.mean[0] == pytest.approx(cut.mean(), abs=0.005) and post.outside_box > 0


def test_a_curved_valley_fails_the_check(rng):
    """A banana: r = [(t1 - t0^2) / 0.01, t0 / 1]: along t0 the valley bends away from the linearisation."""
    def residual(t):
        return np.array([(t[1] - t[0] ** 2) / 0.05, t[0] / 0.5])

    x = np.zeros(2)
    J = np.array([[0.0, 1 / 0.05], [1 / 0.5, 0.0]])
    iv = laplace_intervals(residual(x), J, x, noise=1.0, width_threshold=0.2)
    check = linearity_check(residual, iv, residual(x), -10.0, 10.0)
    assert check.checked[0] and check.poor[0] and "times the linear model's" in check.reasons()[0]
