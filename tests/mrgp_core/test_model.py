"""The fitted MRGP: prediction against independent references, the first iteration, training."""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pytest
from scipy.integrate import quad
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, DotProduct, WhiteKernel

from mrgp_core import Hyperparameters, condition, default_bounds, fit, predicted_overall_error
from mrgp_core import model as model_module
from mrgp_core.kernels import correlation
from mrgp_core.likelihood import DEFAULT_JITTER, mean_basis

SKLEARN_RTOL = 1e-8  # the agreement for one response at fixed hyper-parameters
DENSE_RTOL = 1e-8  # Cholesky/QR route vs explicit inverses
INTERPOLATION_RTOL = 1e-7  # well-conditioned Sigma: the 1e-8 jitter moves the mean by jitter * alpha
FITTED_INTERPOLATION_RTOL = 1e-5  # a fitted noise-free model is smooth, cond(Sigma) ~ r / jitter
REFIT_RTOL = 1e-6  # the same optimisation on rescaled data, up to rounding in L-BFGS-B
VAGUE_PRIOR_RTOL = 1e-6  # linear mean as the limit of a vague Gaussian prior, at tau^2 = 1e6
HELDOUT_SLACK = 0.0  # "no worse than": no slack on the mean over seeds


def one_response(make_rng, r=25, d=3):
    rng = make_rng(20)
    X = rng.uniform(-1, 1, (r, d))
    f = lambda Z: 40.0 + 3.0 * np.sin(3 * Z[:, 0]) + Z[:, 1] ** 2 - 2.0 * Z[:, 2]  # noqa: E731
    Xs = rng.uniform(-1, 1, (60, d))
    return X, f(X), Xs


@pytest.mark.parametrize("nugget", [0.0, 1e-3])
@pytest.mark.parametrize("length_scale", [np.array([0.3]), np.array([0.2, 0.9, 4.0])])
def test_single_response_matches_sklearn_gpr_at_fixed_hyperparameters(make_rng, nugget, length_scale):
    """Zero mean on standardised responses is scikit-learn's ``normalize_y=True``.

    Both subtract the column mean and divide by the column standard deviation,
    then condition a zero-mean GP. The amplitude sklearn needs is the MRGP's
    profiled Q-hat (one response: Q_reg = Q-hat); its kernel is then
    ``Q RBF(sqrt(l)) + Q g White`` with ``alpha = Q jitter``, i.e. ``Q Sigma``.
    sklearn's predictive variance includes the WhiteKernel term, so ours is
    taken with ``observation_noise=True``. The log-likelihoods agree too:
    at ``Q = Q-hat`` the profile likelihood is the full one.
    """
    X, y, Xs = one_response(make_rng)
    model = condition(X, y, Hyperparameters(length_scale, nugget), mean="zero")
    Q = model.terms.Q_reg[0, 0]
    kernel = ConstantKernel(Q, "fixed") * RBF(np.sqrt(length_scale), "fixed")
    if nugget:
        kernel = kernel + WhiteKernel(Q * nugget, "fixed")
    gpr = GaussianProcessRegressor(kernel, alpha=Q * DEFAULT_JITTER, optimizer=None, normalize_y=True).fit(X, y)
    mu_ref, sd_ref = gpr.predict(Xs, return_std=True)
    mean, var = model.predict(Xs, observation_noise=True)
    np.testing.assert_allclose(mean[:, 0], mu_ref, rtol=SKLEARN_RTOL)
    np.testing.assert_allclose(var[:, 0], sd_ref**2, rtol=SKLEARN_RTOL)
    assert model.log_likelihood == pytest.approx(gpr.log_marginal_likelihood_value_, rel=SKLEARN_RTOL)


def test_linear_mean_is_the_limit_of_sklearn_with_a_vague_linear_prior(make_rng):
    """GLS (universal kriging) = a GP whose mean coefficients have a N(0, tau^2 I) prior, as tau -> inf.

    sklearn's ``tau^2 * DotProduct(sigma_0=1)`` is ``tau^2 (1 + x.x')``, the
    covariance that prior induces for ``H = [1, x]``. The difference to our
    GLS mean and variance (with the ``beta`` correction) must shrink like
    ``1/tau^2``; at ``tau^2 = 1e6`` it is below 1e-6.
    """
    X, y, Xs = one_response(make_rng)
    model = condition(X, y, Hyperparameters(np.array([0.3]), 0.0), mean="linear")
    mean, var = model.predict(Xs)
    Q = model.Q[0, 0]
    errors = []
    for tau2 in (1e4, 1e6):
        kernel = ConstantKernel(Q, "fixed") * RBF(np.sqrt(0.3), "fixed") + ConstantKernel(tau2, "fixed") * DotProduct(
            1.0, "fixed")
        gpr = GaussianProcessRegressor(kernel, alpha=Q * DEFAULT_JITTER, optimizer=None).fit(X, y)
        mu_ref, sd_ref = gpr.predict(Xs, return_std=True)
        errors.append(max(np.max(np.abs(mean[:, 0] - mu_ref)) / np.max(np.abs(mu_ref)),
                          np.max(np.abs(var[:, 0] - sd_ref**2)) / np.max(sd_ref**2)))
    assert errors[1] < VAGUE_PRIOR_RTOL
    assert errors[0] / errors[1] > 30  # ~1/tau^2 convergence (100x per decade pair)
    # Eq. (14) without the beta correction is clearly different: the correction is not negligible here.
    _, var_eq14 = model.predict(Xs, mean_uncertainty=False)
    assert np.max(np.abs(var_eq14 - var) / var) > 1e-2


@pytest.mark.parametrize("mean", ["zero", "constant", "linear"])
def test_prediction_matches_dense_universal_kriging_formulas(small_problem, make_rng, mean):
    X, Y = small_problem
    Xs = make_rng(21).uniform(-1.2, 1.2, (30, X.shape[1]))
    hyper = Hyperparameters(np.array([0.25, 0.8]), 1e-4)
    model = condition(X, Y, hyper, mean=mean)
    # Dense reference in standardised units, with explicit inverses.
    Ys = (Y - Y.mean(0)) / Y.std(0)
    Sigma = correlation(X, X, hyper.length_scale) + (hyper.nugget + DEFAULT_JITTER) * np.eye(len(X))
    Ks = correlation(X, Xs, hyper.length_scale)
    Si = np.linalg.inv(Sigma)
    H, Hs = mean_basis(X, mean), mean_basis(Xs, mean)
    if H.shape[1]:
        M = np.linalg.inv(H.T @ Si @ H)
        beta = M @ H.T @ Si @ Ys
        U = Hs.T - H.T @ Si @ Ks
        corr = np.einsum("iw,ij,jw->w", U, M, U)
    else:
        beta, corr = np.zeros((0, Y.shape[1])), 0.0
    mu = Hs @ beta + Ks.T @ Si @ (Ys - H @ beta)
    s = 1.0 - np.einsum("iw,ij,jw->w", Ks, Si, Ks) + corr
    mean_ref = Y.mean(0) + mu * Y.std(0)
    var_ref = np.outer(s, np.diag(model.terms.Q_reg) * Y.std(0) ** 2)
    got_mean, got_var = model.predict(Xs)
    np.testing.assert_allclose(got_mean, mean_ref, rtol=DENSE_RTOL, atol=DENSE_RTOL * np.abs(Y).max())
    np.testing.assert_allclose(got_var, var_ref, rtol=DENSE_RTOL)


def test_noiseless_model_interpolates_its_training_data(small_problem):
    X, Y = small_problem
    scale = Y.std(axis=0)
    model = condition(X, Y, Hyperparameters(np.array([0.05]), 0.0))
    mean, var = model.predict(X)
    np.testing.assert_array_less(np.abs(mean - Y) / scale, INTERPOLATION_RTOL)
    np.testing.assert_array_less(var / np.diag(model.Q), INTERPOLATION_RTOL)
    assert np.all(var >= 0)
    # Away from the data the variance is not small: the interpolation is not trivial.
    _, far = model.predict(X[:3] + 0.3)
    assert np.all(far / np.diag(model.Q) > 1e-2)
    # Trained without a nugget, the (much smoother) model still reproduces its data.
    fitted = fit(X, Y, "gradient", rng=np.random.default_rng(0), nugget=0.0)
    assert fitted.hyperparameters.length_scale[0] > 0.2
    mean, var = fitted.predict(X)
    np.testing.assert_array_less(np.abs(mean - Y) / scale, FITTED_INTERPOLATION_RTOL)
    np.testing.assert_array_less(var / np.diag(fitted.Q), FITTED_INTERPOLATION_RTOL)


def test_each_response_mean_and_variance_equal_single_response_conditioning(wide_problem, make_rng):
    """Q cancels in the posterior mean (Eq. 14) and shrinkage keeps diag(Q): per response, MRGP = one GP."""
    X, Y = wide_problem
    Xs = make_rng(22).uniform(-1, 1, (15, 2))
    hyper = Hyperparameters(np.array([0.5]), 1e-4)
    mean, var = condition(X, Y, hyper).predict(Xs)
    for j in (0, 5, 11):
        m1, v1 = condition(X, Y[:, j], hyper).predict(Xs)
        np.testing.assert_allclose(mean[:, j], m1[:, 0], rtol=1e-9, atol=1e-9 * np.abs(Y[:, j]).max())
        np.testing.assert_allclose(var[:, j], v1[:, 0], rtol=1e-8)


def test_responses_in_other_units_give_the_same_model(small_problem, make_rng):
    X, Y = small_problem
    Xs = make_rng(23).uniform(-1, 1, (10, 2))
    hyper = Hyperparameters(np.array([0.4]), 1e-3)
    ma, va = condition(X, Y, hyper).predict(Xs)
    mb, vb = condition(X, 1e-3 * Y + 7.0, hyper).predict(Xs)
    np.testing.assert_allclose(mb, 1e-3 * ma + 7.0, rtol=1e-12)
    np.testing.assert_allclose(vb, 1e-6 * va, rtol=1e-10)
    a, b = fit(X, Y, rng=np.random.default_rng(1)), fit(X, 1e-3 * Y + 7.0, rng=np.random.default_rng(1))
    np.testing.assert_allclose(b.hyperparameters.length_scale, a.hyperparameters.length_scale, rtol=REFIT_RTOL)
    assert b.hyperparameters.nugget == pytest.approx(a.hyperparameters.nugget, rel=REFIT_RTOL)


def f_two(X):
    """Two smooth, strongly correlated responses of two inputs."""
    base = np.sin(2.5 * X[:, 0]) + 0.6 * np.cos(2.0 * X[:, 1])
    return np.column_stack([base + 0.3 * X[:, 0] * X[:, 1], 2.0 * base - 0.2 * np.sin(3 * X[:, 1])])


def test_correlated_two_response_heldout_error_no_worse_than_two_independent_gps():
    """Same trainer and settings; the MRGP shares the length scale, the independent GPs each fit their own.

    Over 20 random designs of 12 runs, the mean held-out error (standardised
    MSE over both responses, 400 held-out points) of the MRGP must not exceed
    that of two independent GPs, and the MRGP must win more often than not.
    """
    ours, theirs = [], []
    for seed in range(20):
        rng = np.random.default_rng(1000 + seed)
        X, Xt = rng.uniform(-1, 1, (12, 2)), rng.uniform(-1, 1, (400, 2))
        Y, Yt = f_two(X), f_two(Xt)
        sd = Yt.std(axis=0)
        joint = fit(X, Y, rng=np.random.default_rng(seed), nugget=0.0).predict(Xt, return_var=False)[0]
        apart = np.column_stack([
            fit(X, Y[:, j], rng=np.random.default_rng(seed), nugget=0.0).predict(Xt, return_var=False)[0][:, 0]
            for j in range(2)
        ])
        ours.append(np.mean(((joint - Yt) / sd) ** 2))
        theirs.append(np.mean(((apart - Yt) / sd) ** 2))
    ours, theirs = np.array(ours), np.array(theirs)
    assert ours.mean() <= theirs.mean() * (1 + HELDOUT_SLACK)
    assert np.mean(ours <= theirs) > 0.5


@pytest.mark.parametrize(("trainer", "kernel"), [("gradient", "iso"), ("gradient", "ard"), ("sao", "iso"), ("pso", "iso")])
def test_first_iteration_r20_k72_trains_and_predicts_without_nan_or_warnings(first_iteration, trainer, kernel):
    """r = 20 runs, k = 72 responses: Q-hat has rank <= 13, and Table 1's full budgets are used."""
    X, Y, X_new = first_iteration
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = fit(X, Y, trainer, rng=np.random.default_rng(5), kernel=kernel)
        mean, var = model.predict(X_new)
        score = model.predicted_overall_error(X_new, "expected_abs")
    assert np.linalg.matrix_rank(model.terms.Q_hat) <= 20 - 7
    assert np.isfinite(model.log_likelihood)
    assert mean.shape == var.shape == (500, 72) and score.shape == (500,)
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(np.isfinite(score))
    assert np.all(var >= 0)
    lo, hi = model.training.bounds[:, 0], model.training.bounds[:, 1]
    assert np.all(model.training.result.x >= lo) and np.all(model.training.result.x <= hi)
    # The responses span four decades; the predictions follow each column's scale.
    ratio = np.std(mean, axis=0) / np.std(Y, axis=0)
    assert np.all((ratio > 1e-2) & (ratio < 1e2))
    if trainer in ("sao", "pso"):
        assert model.training.result.nfev == {"sao": 1 + 16 * 400, "pso": 10_000}[trainer]


def test_paper_trainers_reach_the_gradient_optimum_on_the_first_iteration(first_iteration):
    X, Y, _ = first_iteration
    nll = {name: fit(X, Y, name, rng=np.random.default_rng(6)).training.result.fun for name in ("gradient", "pso")}
    assert nll["pso"] == pytest.approx(nll["gradient"], abs=1e-3)


@pytest.mark.parametrize("trainer", ["sao", "pso"])
def test_stochastic_training_is_reproducible_for_a_fixed_seed(small_problem, trainer):
    X, Y = small_problem
    opts = {"sao": {"iterations_per_temperature": 50}, "pso": {"swarm_size": 20, "max_evaluations": 600}}[trainer]
    runs = [fit(X, Y, trainer, rng=np.random.default_rng(s), options=opts) for s in (9, 9, 10)]
    assert runs[0].hyperparameters.as_dict() == runs[1].hyperparameters.as_dict()
    np.testing.assert_array_equal(runs[0].training.result.history, runs[1].training.result.history)
    assert not np.array_equal(runs[0].training.result.history, runs[2].training.result.history)


def test_l_upper_from_the_previous_iteration_bounds_the_search(small_problem):
    X, Y = small_problem
    free = fit(X, Y, rng=np.random.default_rng(2))
    cap = 0.5 * free.hyperparameters.length_scale[0]
    capped = fit(X, Y, rng=np.random.default_rng(2), l_upper=cap)
    assert capped.hyperparameters.length_scale[0] <= cap * (1 + 1e-12)
    assert capped.training.bounds[0, 1] == pytest.approx(np.log(cap))
    assert capped.log_likelihood <= free.log_likelihood


def test_default_bounds_bracket_the_data_scales(make_rng):
    X = make_rng(24).uniform(-1, 1, (20, 3))
    lo, hi = default_bounds(X, "iso")
    sq = np.sum((X[:, None] - X[None]) ** 2, axis=-1)
    assert lo[0] == pytest.approx(sq[sq > 0].min() / 100) and hi[0] == pytest.approx(100 * np.sum(np.ptp(X, 0) ** 2))
    lo, hi = default_bounds(X, "ard", l_upper=[1.0, 2.0, 3.0])
    assert lo.shape == hi.shape == (3,) and np.all(lo < hi) and list(hi) == [1.0, 2.0, 3.0]
    lo, hi = default_bounds(X, "iso", l_lower=5.0, l_upper=1.0)
    assert lo[0] == pytest.approx(1e-3)


def test_constant_response_is_predicted_as_that_constant(small_problem):
    X, Y = small_problem
    Y = np.column_stack([Y, np.full(len(X), 2.5)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = fit(X, Y, rng=np.random.default_rng(3))
        mean, var = model.predict(X + 0.1)
    np.testing.assert_allclose(mean[:, -1], 2.5, rtol=1e-12)
    assert np.all(var[:, -1] < 1e-8) and np.all(np.isfinite(var))


def test_prediction_in_chunks_equals_one_block(small_problem, make_rng, monkeypatch):
    X, Y = small_problem
    model = condition(X, Y, Hyperparameters(np.array([0.4]), 1e-3))
    Xs = make_rng(25).uniform(-1, 1, (23, 2))
    whole = model.predict(Xs)
    monkeypatch.setattr(model_module, "_PREDICT_CHUNK", 5)
    parts = model.predict(Xs)
    for a, b in zip(whole, parts):
        np.testing.assert_allclose(a, b, rtol=1e-11)


def test_predicted_overall_error_is_eq_6b_and_its_expectation(make_rng):
    rng = make_rng(26)
    mean = rng.normal(0, 0.2, (4, 5))
    var = rng.uniform(0.001, 0.05, (4, 5))
    var[0, 0] = 0.0
    np.testing.assert_allclose(predicted_overall_error(mean), np.mean(np.abs(mean), axis=1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        expected = predicted_overall_error(mean, var, "expected_abs")
    sd = np.sqrt(var)
    by_quadrature = np.array([
        np.mean([
            abs(m) if s == 0 else
            quad(lambda e, m=m, s=s: abs(e) * np.exp(-0.5 * ((e - m) / s) ** 2) / (s * np.sqrt(2 * np.pi)),
                 m - 12 * s, m + 12 * s, points=[0.0] if abs(m) < 12 * s else None)[0]
            for m, s in zip(mrow, srow)
        ])
        for mrow, srow in zip(mean, sd)
    ])
    np.testing.assert_allclose(expected, by_quadrature, rtol=1e-9)
    assert np.all(expected >= predicted_overall_error(mean))
    with pytest.raises(ValueError, match="variance"):
        predicted_overall_error(mean, None, "expected_abs")
    with pytest.raises(ValueError, match="valid criteria"):
        predicted_overall_error(mean, var, "median")


def test_unknown_trainer_is_refused_with_the_valid_names(small_problem):
    X, Y = small_problem
    with pytest.raises(ValueError, match="valid trainers are gradient, pso, sao"):
        fit(X, Y, "bayesopt", rng=np.random.default_rng(0))


def test_fit_reports_sigma_f_one_and_logs_a_summary(small_problem, caplog):
    X, Y = small_problem
    with caplog.at_level(logging.INFO, logger="mrgp_core.model"):
        model = fit(X, Y, rng=np.random.default_rng(4))
    assert model.hyperparameters.sigma_f == 1.0
    assert model.hyperparameters.as_dict()["kernel"] == "iso"
    assert any("MRGP fit (gradient" in rec.getMessage() for rec in caplog.records)
    assert model.training.trainer == "gradient" and model.training.seconds > 0
