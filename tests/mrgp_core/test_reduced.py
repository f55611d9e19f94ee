"""The MRGP in a reduced output basis, against independent references.

References: numpy's SVD (the basis), the full MRGP of :mod:`mrgp_core.model`
(itself checked against scikit-learn in test_model.py) on outputs that lie
exactly in a low-dimensional subspace, fresh held-out data (the truncation
variance), the unchunked selection criterion, and tracemalloc (no k x k
array when k > n).
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from mrgp_core import Hyperparameters, condition, predicted_overall_error
from mrgp_core import reduced as reduced_module
from mrgp_core.reduced import condition_reduced, fit_reduced, output_basis

# Gram route vs LAPACK SVD: the basis error is eps * (s_1 / s_i)^2, about 1e-13 for these
# well-conditioned latent mixtures.
BASIS_ATOL = 1e-9
GRAM_EIG_ATOL = 1e-12  # n eps with n <= 100, and margin
# Same linear predictor on the same subspace: only rounding differs (the data span 4 decades
# after un-standardising, so compare relative to the largest mean).
SUBSPACE_RTOL = 1e-10
# The variances use the floor of Q_reg (1e-10 relative) differently in k and r dimensions.
SUBSPACE_VAR_RTOL = 1e-8
HYPER = Hyperparameters(length_scale=np.array([0.6]), nugget=1e-6)


def latent(Z: np.ndarray) -> np.ndarray:
    """Three smooth functions of the inputs, shape (w, 3)."""
    return np.column_stack([np.sin(2 * Z[:, 0]) + Z[:, 1], np.cos(3 * Z[:, 1] * Z[:, 2]), Z[:, 0] ** 2 - Z[:, 2]])


def subspace_data(make_rng, n=40, k=30, w=50, d=3):
    """Responses exactly in a 3-dimensional affine subspace, with scales over 4 decades."""
    rng = make_rng(160)
    A = rng.standard_normal((3, k))
    centre = 5.0 * rng.standard_normal(k)
    scale = 10.0 ** rng.uniform(-2, 2, k)
    X, Xs = rng.uniform(-1, 1, (n, d)), rng.uniform(-1, 1, (w, d))
    return X, centre + (latent(X) @ A) * scale, Xs


def frf_like(X: np.ndarray, k: int) -> np.ndarray:
    """Smooth responses over a 'frequency' axis with a parameter-dependent resonance: not low rank."""
    f = np.linspace(0.0, 1.0, k)
    peak = 0.5 + 0.15 * X[:, [0]] + 0.05 * X[:, [1]]
    width = 0.05 + 0.02 * (X[:, [2]] + 1.0)
    return np.log1p(1.0 / (((f - peak) / width) ** 2 + 0.05)) + 0.3 * X[:, [1]] * f


def test_basis_matches_numpy_svd_and_follows_the_rank_rule(make_rng):
    rng = make_rng(161)
    X = rng.uniform(-1, 1, (60, 3))
    Y = frf_like(X, 200)
    Ys = (Y - Y.mean(axis=0)) / Y.std(axis=0)
    _, sv, Vt = np.linalg.svd(Ys, full_matrices=False)
    frac = np.cumsum(sv**2) / np.sum(sv**2)
    for variance in (0.9, 0.99, 0.999):
        ob = output_basis(Y, variance)
        r = ob.n_components
        assert frac[r - 1] >= variance * (1 - 1e-12) and (r == 1 or frac[r - 2] < variance)
        # eigenvalues of the Gram matrix carry an absolute error of about n eps s_1^2
        np.testing.assert_allclose(ob.singular_values**2, sv**2, rtol=0, atol=GRAM_EIG_ATOL * sv[0] ** 2)
        # same subspace: the cosines of the principal angles are all 1
        cosines = np.linalg.svd(ob.basis.T @ Vt[:r].T, compute_uv=False)
        np.testing.assert_allclose(cosines, 1.0, atol=BASIS_ATOL)
        np.testing.assert_allclose(ob.basis.T @ ob.basis, np.eye(r), atol=BASIS_ATOL)
        np.testing.assert_allclose(ob.captured, frac[r - 1], atol=BASIS_ATOL)
    assert output_basis(Y, 0.999, max_components=2).n_components == 2


@pytest.mark.parametrize("mean", ["zero", "linear"])
def test_exact_subspace_gives_the_full_mrgp(make_rng, mean):
    """On rank-3 outputs the reduced model is the full MRGP's linear predictor on 3 directions.

    The posterior mean is linear in the responses at fixed Sigma, so it equals the full
    model's. With no shrinkage the full Q^ is V Q_W^ V^T, so the variances agree too (the
    default shrinkage pulls a k x k and an r x r matrix to different diagonals).
    """
    X, Y, Xs = subspace_data(make_rng)
    full = condition(X, Y, HYPER, mean=mean, shrinkage=0.0)
    red = condition_reduced(X, Y, HYPER, mean=mean, shrinkage=0.0)
    assert red.n_components == 3
    np.testing.assert_allclose(red.outputs.truncation_variance, 0.0, atol=1e-20)
    m_full, v_full = full.predict(Xs)
    m_red, v_red = red.predict(Xs)
    np.testing.assert_allclose(m_red, m_full, rtol=0, atol=SUBSPACE_RTOL * np.abs(m_full).max())
    np.testing.assert_allclose(v_red, v_full, rtol=SUBSPACE_VAR_RTOL, atol=SUBSPACE_VAR_RTOL * v_full.max())
    for criterion in ("mean_abs", "expected_abs"):
        np.testing.assert_allclose(red.predicted_overall_error(Xs, criterion, precision="double"),
                                   full.predicted_overall_error(Xs, criterion), rtol=SUBSPACE_VAR_RTOL)


def test_cross_validated_truncation_variance_matches_explicit_folds(make_rng):
    """The Gram-matrix shortcut against fold-by-fold numpy SVDs of the copied rows."""
    rng = make_rng(169)
    X = rng.uniform(-1, 1, (37, 3))  # folds of unequal size
    Y = frf_like(X, 90)
    for n_folds in (2, 5):
        ob = output_basis(Y, 0.99, n_folds=n_folds)
        Ys = (Y - Y.mean(axis=0)) / Y.std(axis=0)
        fold = np.arange(Y.shape[0]) % n_folds
        sq = np.zeros(Y.shape[1])
        for f in range(n_folds):
            m = Ys[fold != f].mean(axis=0)
            _, _, Vt = np.linalg.svd(Ys[fold != f] - m, full_matrices=False)
            E = Ys[fold == f] - m
            E -= (E @ Vt[: ob.n_components].T) @ Vt[: ob.n_components]
            sq += np.sum(E**2, axis=0)
        np.testing.assert_allclose(ob.truncation_variance, sq / Y.shape[0], rtol=1e-8, atol=1e-12)


def test_truncation_variance_is_the_held_out_residual(make_rng):
    """The cross-validated discrepancy of the discarded directions matches fresh data's, per response."""
    rng = make_rng(162)
    k = 150
    X, Xt = rng.uniform(-1, 1, (80, 3)), rng.uniform(-1, 1, (400, 3))
    Y, Yt = frf_like(X, k), frf_like(Xt, k)
    ob = output_basis(Y, 0.99)
    assert 1 < ob.n_components < 20
    Et = (Yt - ob.centre) / ob.scale
    Et -= (Et @ ob.basis) @ ob.basis.T
    held_out = np.mean(Et**2, axis=0)
    Ein = (Y - ob.centre) / ob.scale - ob.coefficients @ ob.basis.T
    in_sample = np.mean(Ein**2, axis=0)
    ratio = np.mean(ob.truncation_variance) / np.mean(held_out)
    assert 0.5 < ratio < 2.0, ratio
    # the in-sample residual, which the basis was fitted to, is the optimistic one
    assert np.mean(in_sample) < np.mean(ob.truncation_variance)
    # per response (80 rows give noisy, heavy-tailed estimates) the order is right for nine in
    # ten of the responses whose residual is not negligible
    big = held_out > 0.1 * held_out.max()
    per_response = ob.truncation_variance[big] / held_out[big]
    assert np.mean((per_response > 1 / 3) & (per_response < 3)) >= 0.9, np.sort(per_response)


def test_predictive_variance_covers_the_held_out_error(make_rng):
    """Standardised held-out errors have mean square of order one: the variance is honest."""
    rng = make_rng(163)
    X, Xt = rng.uniform(-1, 1, (80, 3)), rng.uniform(-1, 1, (200, 3))
    Y, Yt = frf_like(X, 120), frf_like(Xt, 120)
    model = fit_reduced(X, Y, rng=make_rng(164), variance=0.99)
    mean, var = model.predict(Xt)
    z2 = np.mean((mean - Yt) ** 2 / var)
    _, var_kept = model.predict(Xt, truncation=False)
    z2_kept = np.mean((mean - Yt) ** 2 / var_kept)
    assert 0.2 < z2 < 5.0, z2
    assert z2_kept > 2 * z2  # without the discrepancy term the variance is too small


def test_chunked_criterion_equals_the_unchunked_one(make_rng, monkeypatch):
    rng = make_rng(165)
    X, Xs = rng.uniform(-1, 1, (50, 3)), rng.uniform(-1, 1, (103, 3))
    model = condition_reduced(X, frf_like(X, 64), HYPER, variance=0.99)
    monkeypatch.setattr(reduced_module, "_CHUNK_ELEMENTS", 64 * 10)  # chunks of 10 (expected) and 40 (mean) rows
    mean, var = model.predict(Xs)
    for criterion in ("mean_abs", "expected_abs"):
        np.testing.assert_allclose(model.predicted_overall_error(Xs, criterion, precision="double"),
                                   predicted_overall_error(mean, var, criterion), rtol=1e-12)


def test_single_precision_criterion_is_within_its_rounding_bound(make_rng):
    """|single - double| <= (r + 3) eps_32 mean_j (|centre_j| + sum_i |c_i| |B_ij|), the dot-product bound."""
    rng = make_rng(170)
    X, Xs = rng.uniform(-1, 1, (60, 3)), rng.uniform(-1, 1, (500, 3))
    Y = 3.0 + frf_like(X, 300)  # an offset, so the centre row carries weight
    model = condition_reduced(X, Y, HYPER, variance=0.999)
    single = model.predicted_overall_error(Xs)
    double = model.predicted_overall_error(Xs, precision="double")
    C, _ = model.coefficients.predict_factors(Xs, return_var=False)
    B = model.outputs.basis.T * model.outputs.scale
    terms = np.mean(np.abs(model.outputs.centre) + np.abs(C) @ np.abs(B), axis=1)
    bound = (model.n_components + 3) * np.finfo(np.float32).eps * terms
    assert single.dtype == np.float64
    assert np.all(np.abs(single - double) <= bound)
    assert np.any(single != double)  # it did run in single precision


def test_more_responses_than_runs_without_a_k_by_k_array(make_rng):
    """k = 2,000 responses, n = 40 runs: fit and rank 200 candidates well below one k x k array."""
    rng = make_rng(166)
    n, k, w = 40, 2000, 200
    X, Xs = rng.uniform(-1, 1, (n, 3)), rng.uniform(-1, 1, (w, 3))
    Y = frf_like(X, k)
    kk_bytes = k * k * 8
    tracemalloc.start()
    try:
        model = fit_reduced(X, Y, rng=make_rng(167))
        score = model.predicted_overall_error(Xs)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        expected = model.predicted_overall_error(Xs, "expected_abs")
        _, peak_expected = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < kk_bytes / 4, (peak, kk_bytes)
    assert peak_expected < kk_bytes / 2, (peak_expected, kk_bytes)  # its formula makes ~8 chunk-sized temporaries
    assert model.n_components <= n - 1 and model.coefficients.Q.shape == (model.n_components,) * 2
    assert score.shape == (w,) and np.all(np.isfinite(score))
    # and the scores are right: against the direct formula on the (w, k) prediction
    mean, var = model.predict(Xs)
    assert mean.shape == (w, k)
    np.testing.assert_allclose(score, predicted_overall_error(mean), rtol=1e-5)  # single precision, bound above
    np.testing.assert_allclose(expected, predicted_overall_error(mean, var, "expected_abs"), rtol=1e-12)
    # the update flow stores hyper-parameters and re-conditions: the basis is rebuilt identically
    again = condition_reduced(X, Y, model.hyperparameters)
    assert again.n_components == model.n_components
    np.testing.assert_allclose(again.predicted_overall_error(Xs), score, rtol=1e-12)


def test_bad_input_is_refused(make_rng):
    rng = make_rng(168)
    Y = rng.standard_normal((10, 5))
    with pytest.raises(ValueError, match="variance"):
        output_basis(Y, 0.0)
    with pytest.raises(ValueError, match="n_folds"):
        output_basis(Y, n_folds=1)
    with pytest.raises(ValueError, match="max_components"):
        output_basis(Y, max_components=0)
    with pytest.raises(ValueError, match="constant"):
        output_basis(np.ones((10, 5)))
    with pytest.raises(ValueError, match="finite"):
        output_basis(np.where(Y > 1, np.nan, Y))
    ob = output_basis(Y)
    with pytest.raises(ValueError, match=r"\(w, 5\)"):
        ob.project(Y[:, :4])
    model = condition_reduced(rng.uniform(-1, 1, (10, 2)), Y, HYPER)
    with pytest.raises(ValueError, match="criterion"):
        model.predicted_overall_error(np.zeros((3, 2)), "median")
    with pytest.raises(ValueError, match="precision"):
        model.predicted_overall_error(np.zeros((3, 2)), precision="half")
