"""Profile likelihood (Eqs. 9-12) against the explicit Kronecker form, and its gradient.

The reference builds the (r k) x (r k) covariance ``Q (x) Sigma`` with
``numpy.kron``, estimates ``beta`` by GLS on ``vec(Y)`` with that full
covariance, and evaluates the Gaussian log-density with scipy; the code under
test never forms the Kronecker product.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from mrgp_core import likelihood as lk
from mrgp_core.kernels import correlation_from_squared, squared_distances

LOGLIK_RTOL = 1e-9  # Cholesky route vs dense Kronecker inverse on well-conditioned problems
BETA_ATOL = 1e-9
FD_STEP = 1e-4
FD_RTOL = 1e-6  # fourth-order central differences, relative to the largest gradient entry
INVARIANCE_RTOL = 1e-10


def sigma_of(X, l, nugget=0.0):
    Sigma = correlation_from_squared(squared_distances(X), np.array([l]))
    return Sigma + (nugget + lk.DEFAULT_JITTER) * np.eye(X.shape[0])


def finite_difference_gradient(fun, theta, h=FD_STEP):
    """Fourth-order central differences (error O(h^4), so h can be large enough to beat rounding)."""
    grad = np.empty(theta.size)
    for i, e in enumerate(np.eye(theta.size) * h):
        grad[i] = (-fun(theta + 2 * e) + 8 * fun(theta + e) - 8 * fun(theta - e) + fun(theta - 2 * e)) / (12 * h)
    return grad


def reference_q_reg(Q_hat, lam):
    """The documented rule, written out independently."""
    k = Q_hat.shape[0]
    return (1 - lam) * Q_hat + lam * np.diag(np.diag(Q_hat)) + lk.Q_FLOOR * np.trace(Q_hat) / k * np.eye(k)


def kronecker_reference(Sigma, H, Y, lam):
    """beta (GLS on vec Y with the full covariance), Q-hat, Q_reg and Eq. (10), all dense."""
    r, k = Y.shape
    q = H.shape[1]
    y = Y.reshape(-1, order="F")  # vec(): columns stacked
    Hk = np.kron(np.eye(k), H)
    Sinv = np.linalg.inv(Sigma)
    if q:
        # GLS weights with any Q give the same beta; use Q = I for the estimate itself.
        Ci = np.kron(np.eye(k), Sinv)
        b = np.linalg.solve(Hk.T @ Ci @ Hk, Hk.T @ Ci @ y)
    else:
        b = np.empty(0)
    beta = b.reshape(q, k, order="F")
    E = Y - H @ beta
    Q_hat = E.T @ Sinv @ E / r
    Q_reg = reference_q_reg(Q_hat, lam)
    cov = np.kron(Q_reg, Sigma)
    # The GLS estimate must not depend on Q: re-estimate with the full covariance.
    if q:
        Ci = np.linalg.inv(cov)
        b_full = np.linalg.solve(Hk.T @ Ci @ Hk, Hk.T @ Ci @ y)
        np.testing.assert_allclose(b_full, b, atol=BETA_ATOL * max(1, np.abs(b).max()))
    loglik = multivariate_normal(mean=Hk @ b, cov=cov).logpdf(y)
    return beta, Q_hat, Q_reg, loglik


@pytest.mark.parametrize("mean", ["zero", "constant", "linear"])
@pytest.mark.parametrize("lam", ["auto", 0.0, 0.3])
@pytest.mark.parametrize("nugget", [0.0, 1e-3])
def test_profile_likelihood_equals_direct_kronecker_eq10(small_problem, mean, lam, nugget):
    X, Y = small_problem
    Ys, _, _ = lk.standardise(Y)
    H = lk.mean_basis(X, mean)
    Sigma = sigma_of(X, 0.4, nugget)
    terms = lk.profile(Sigma, H, Ys, lam)
    lam_value = lk.shrinkage_weight(lam, *Ys.shape[:1], H.shape[1], Ys.shape[1])
    beta, Q_hat, Q_reg, ref = kronecker_reference(Sigma, H, Ys, lam_value)
    np.testing.assert_allclose(terms.beta, beta, atol=BETA_ATOL)
    np.testing.assert_allclose(terms.Q_hat, Q_hat, rtol=LOGLIK_RTOL, atol=1e-12)
    np.testing.assert_allclose(terms.Q_reg, Q_reg, rtol=LOGLIK_RTOL, atol=1e-12)
    assert terms.log_likelihood == pytest.approx(ref, rel=LOGLIK_RTOL)


@pytest.mark.parametrize("lam", ["auto", 0.05, 0.6])
def test_profile_likelihood_equals_kronecker_when_q_hat_is_singular(wide_problem, lam):
    X, Y = wide_problem
    Ys, _, _ = lk.standardise(Y)
    H = lk.mean_basis(X, "linear")
    r, k = Ys.shape
    Sigma = sigma_of(X, 0.5, 1e-4)
    terms = lk.profile(Sigma, H, Ys, lam)
    # Eq. (12)'s Q has rank r - q < k here: Eq. (10) would be -inf without the regularisation.
    assert np.linalg.matrix_rank(terms.Q_hat, tol=1e-10 * np.trace(terms.Q_hat)) == r - H.shape[1] < k
    _, _, _, ref = kronecker_reference(Sigma, H, Ys, lk.shrinkage_weight(lam, r, H.shape[1], k))
    assert np.isfinite(terms.log_likelihood)
    assert terms.log_likelihood == pytest.approx(ref, rel=LOGLIK_RTOL)


def test_regularised_q_is_positive_definite_and_keeps_each_response_variance(wide_problem):
    X, Y = wide_problem
    Ys, _, _ = lk.standardise(Y)
    terms = lk.profile(sigma_of(X, 0.5), lk.mean_basis(X, "linear"), Ys)
    assert np.linalg.eigvalsh(terms.Q_reg).min() > 0
    k = Ys.shape[1]
    floor = lk.Q_FLOOR * np.trace(terms.Q_hat) / k
    np.testing.assert_allclose(np.diag(terms.Q_reg), np.diag(terms.Q_hat) + floor, rtol=1e-14)


def test_without_shrinkage_q_hat_maximises_eq10_and_the_quadratic_term_is_rk_over_2(small_problem, make_rng):
    X, Y = small_problem
    Ys, _, _ = lk.standardise(Y)
    H = lk.mean_basis(X, "linear")
    Sigma = sigma_of(X, 0.4)
    r, k = Ys.shape
    terms = lk.profile(Sigma, H, Ys, 0.0)
    # Trace identity: with Q = Q-hat, vec(E)^T (Q (x) Sigma)^-1 vec(E) = tr(Q^-1 E^T Sigma^-1 E) = r k.
    _, logdet_q = np.linalg.slogdet(terms.Q_hat)
    _, logdet_s = np.linalg.slogdet(Sigma)
    closed_form = -0.5 * (r * k * np.log(2 * np.pi) + r * logdet_q + k * logdet_s + r * k)
    assert terms.log_likelihood == pytest.approx(closed_form, rel=1e-8)
    # Any other Q gives a smaller Eq. (10).
    beta = terms.beta
    y = Ys.reshape(-1, order="F")
    mean = (H @ beta).reshape(-1, order="F")
    rng = make_rng()
    for _ in range(5):
        A = rng.normal(scale=0.2, size=(k, k))
        other = terms.Q_hat + A @ A.T * np.trace(terms.Q_hat) / k
        assert multivariate_normal(mean, np.kron(other, Sigma)).logpdf(y) < terms.log_likelihood


def test_sigma_f_is_not_identifiable_the_profile_likelihood_ignores_it(small_problem):
    X, Y = small_problem
    Ys, _, _ = lk.standardise(Y)
    H = lk.mean_basis(X, "linear")
    Sigma = sigma_of(X, 0.4, 1e-3)
    base = lk.profile(Sigma, H, Ys)
    for sigma_f in (0.1, 3.0, 10.0):
        scaled = lk.profile(sigma_f**2 * Sigma, H, Ys)
        assert scaled.log_likelihood == pytest.approx(base.log_likelihood, rel=INVARIANCE_RTOL)
        np.testing.assert_allclose(scaled.Q_reg * sigma_f**2, base.Q_reg, rtol=1e-9)
        np.testing.assert_allclose(scaled.beta, base.beta, atol=1e-10)


@pytest.mark.parametrize("kernel", ["iso", "ard"])
@pytest.mark.parametrize("nugget", ["fit", 0.0, 1e-3])
@pytest.mark.parametrize("problem", ["small_problem", "wide_problem"])
def test_analytic_gradient_matches_finite_differences(request, make_rng, kernel, nugget, problem):
    X, Y = request.getfixturevalue(problem)
    Ys, _, _ = lk.standardise(Y)
    lik = lk.ProfileLikelihood(X, Ys, kernel=kernel, mean="linear", nugget=nugget)
    rng = make_rng(7)
    for _ in range(3):
        theta = np.log(rng.uniform(0.1, 1.5, lik.n_params))
        if lik.fit_nugget:
            theta[-1] = np.log(rng.uniform(1e-4, 1e-1))
        value, grad = lik.negative_and_grad(theta)
        assert value == pytest.approx(lik.negative(theta), rel=1e-12)
        fd = finite_difference_gradient(lik.negative, theta)
        np.testing.assert_allclose(grad, fd, atol=FD_RTOL * np.abs(fd).max())


@pytest.mark.parametrize("mean", ["zero", "constant"])
def test_gradient_is_exact_for_other_means_and_strong_shrinkage(small_problem, mean):
    X, Y = small_problem
    Ys, _, _ = lk.standardise(Y)
    lik = lk.ProfileLikelihood(X, Ys, kernel="ard", mean=mean, nugget="fit", shrinkage=0.9)
    theta = np.log([0.3, 0.8, 1e-2])
    _, grad = lik.negative_and_grad(theta)
    fd = finite_difference_gradient(lik.negative, theta)
    np.testing.assert_allclose(grad, fd, atol=FD_RTOL * np.abs(fd).max())


def test_standardise_keeps_constant_columns_finite():
    Y = np.column_stack([np.arange(5.0), np.full(5, 3.0), 1e6 * np.arange(5.0) ** 2])
    Ys, centre, scale = lk.standardise(Y)
    assert np.all(np.isfinite(Ys))
    np.testing.assert_allclose(Ys[:, 1], 0.0)
    assert scale[1] == 1.0 and centre[1] == 3.0
    np.testing.assert_allclose(Ys.std(axis=0)[[0, 2]], 1.0)
    np.testing.assert_allclose(centre + Ys * scale, Y)


def test_shrinkage_weight_rule_and_validation():
    assert lk.shrinkage_weight("auto", r=20, q=7, k=72) == pytest.approx(72 / 85)
    assert lk.shrinkage_weight("auto", r=240, q=7, k=72) == pytest.approx(72 / 305)
    assert lk.shrinkage_weight("auto", r=5, q=7, k=72) == 1.0
    assert lk.shrinkage_weight(0.25, r=20, q=7, k=72) == 0.25
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        lk.shrinkage_weight(1.5, r=20, q=7, k=72)
    with pytest.raises(ValueError, match="auto"):
        lk.shrinkage_weight("ledoit", r=20, q=7, k=72)


def test_unknown_mean_is_refused():
    with pytest.raises(ValueError, match="valid means are zero, constant, linear"):
        lk.mean_basis(np.zeros((3, 2)), "quadratic")


def test_a_mean_with_more_columns_than_runs_is_refused_by_name(rng):
    """The linear mean [1, x] on 9 inputs has 10 columns: 9 runs cannot fit it (the paper's loop with -q 4 on a
    9-segment model failed inside scipy with 'expected square matrix'); 10 leave its residual to the shrinkage of Q,
    which the loop relies on when one of its first runs fails."""
    Y = rng.normal(size=(10, 3))
    X = rng.uniform(size=(10, 9))
    with pytest.raises(ValueError, match="the linear mean has 10 columns on 9 inputs: its fit needs at least 10 "
                                         "training runs, got 9"):
        lk.ProfileLikelihood(X[:9], Y[:9], mean="linear")
    lik = lk.ProfileLikelihood(X, Y, mean="linear")
    assert np.isfinite(lik.negative(np.zeros(lik.n_params)))
    lk.ProfileLikelihood(X[:1], Y[:1], mean="constant")
