"""The random error of an averaged H1 estimate from coherence and averages (fe_core.inference.coherence_noise),
checked by Monte Carlo: simulate n averages of force and noisy response spectra with a known coherence, estimate
H1 many times, and compare the spread of ln|H1| and of its phase with the formula."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.inference.coherence_noise import frf_random_error, t_degrees_of_freedom

TRIALS = 40_000


def _h1_trials(gamma2: float, n: int, rng, force_spread: float = 0.0):
    """``TRIALS`` H1 estimates of H = 1 from ``n`` averages, response noise set for coherence ``gamma2``.

    Force spectra of magnitude 1 (times a uniform factor in [1 - spread, 1 + spread]) with random phase, as
    hammer hits; response noise complex Gaussian with the variance that makes the true coherence
    ``|H|^2 S_ff / (|H|^2 S_ff + S_nn) = gamma2`` (``S_ff = 1`` without spread).
    """
    H = 0.7 * np.exp(0.4j)
    force = np.exp(2j * np.pi * rng.random((TRIALS, n)))
    if force_spread:
        force *= rng.uniform(1 - force_spread, 1 + force_spread, (TRIALS, n))
    s_nn = abs(H) ** 2 * (1 - gamma2) / gamma2
    noise = np.sqrt(s_nn / 2) * (rng.standard_normal((TRIALS, n)) + 1j * rng.standard_normal((TRIALS, n)))
    response = H * force + noise
    sxf = np.sum(response * np.conj(force), axis=1)
    sff = np.sum(np.abs(force) ** 2, axis=1)
    sxx = np.sum(np.abs(response) ** 2, axis=1)
    ratio = (sxf / sff) / H
    return np.log(np.abs(ratio)), np.angle(ratio), np.abs(sxf) ** 2 / (sff * sxx)


@pytest.mark.parametrize("gamma2, n", [(0.99, 5), (0.95, 3), (0.9, 10), (0.8, 20), (0.5, 40)])
def test_spread_of_ln_amplitude_and_phase_matches_bendat_piersol(gamma2, n):
    rng = np.random.default_rng(1000 + n)
    log_amp, phase, _ = _h1_trials(gamma2, n, rng)
    eps = float(frf_random_error(gamma2, n, coherence_estimated=False))
    # Tolerance: 4 standard errors of a standard deviation from TRIALS Gaussian draws, plus the first order
    # the formula neglects (ln|1 + z| = Re z + O(|z|^2): a relative change of order eps^2).
    tol = 4 / np.sqrt(2 * (TRIALS - 1)) + eps**2
    assert np.std(log_amp) == pytest.approx(eps, rel=tol)
    assert np.std(phase) == pytest.approx(eps, rel=tol)
    assert abs(np.mean(phase)) < 4 * eps / np.sqrt(TRIALS)  # H1 is unbiased in phase


@pytest.mark.parametrize("gamma2, n", [(0.9, 10), (0.8, 5), (0.97, 20)])
def test_with_hammer_like_force_variation_and_the_estimated_coherence(gamma2, n):
    """Hits +-30 % in force, the coherence estimated from the same averages (what a file holds): the rms of the
    per-trial prediction (n - 1 degrees of freedom) equals the spread. Given the forces, the prediction squared
    is the unbiased estimate of H1's conditional variance, so this holds whatever the force variation; the
    formula with n at the estimated coherence comes out sqrt((n - 1) / n) too small (5 % at 10 hits)."""
    rng = np.random.default_rng(7 + n)
    log_amp, phase, estimated = _h1_trials(gamma2, n, rng, force_spread=0.3)
    predicted = np.sqrt(np.mean(frf_random_error(estimated, n) ** 2))
    tol = 4 / np.sqrt(2 * (TRIALS - 1)) + predicted**2
    assert np.std(log_amp) == pytest.approx(predicted, rel=tol)
    assert np.std(phase) == pytest.approx(predicted, rel=tol)
    naive = np.sqrt(np.mean(frf_random_error(estimated, n, coherence_estimated=False) ** 2))
    assert naive == pytest.approx(predicted * np.sqrt((n - 1) / n), rel=1e-12)
    assert np.std(log_amp) > naive * (1 + tol) or n >= 20


@pytest.mark.parametrize("n", [5, 10])
def test_standardised_residuals_are_student_t_with_2_n_minus_1_degrees_of_freedom(n):
    """Errors divided by the prediction from the estimated coherence: mean square nu / (nu - 2), not 1, and the
    quantiles of Student-t (nu = 2 (n - 1)); a chi-square test taking them as standard normal calls noise
    structure (4/3 at 5 hits)."""
    from scipy import stats

    rng = np.random.default_rng(50 + n)
    log_amp, phase, estimated = _h1_trials(0.9, n, rng, force_spread=0.3)
    z = np.concatenate([log_amp, phase]) / np.tile(frf_random_error(estimated, n), 2)
    nu = float(t_degrees_of_freedom(n))
    # The mean of z^2 (variance nu/(nu-2)) from 2 x TRIALS draws: its standard error from t's fourth moment,
    # 3 nu^2 / ((nu - 2)(nu - 4)), and the first order neglected (eps^2 ~ 0.6 %).
    var, m4 = nu / (nu - 2), 3 * nu**2 / ((nu - 2) * (nu - 4))
    tol = 4 * np.sqrt((m4 - var**2) / z.size) + 0.01 * var
    assert np.mean(z**2) == pytest.approx(var, abs=tol)
    for q in (0.9, 0.975):  # a quantile of 2 x TRIALS draws is good to about 1 %; 3 % allows eps^2 and that
        assert np.quantile(np.abs(z), q) == pytest.approx(stats.t.ppf(0.5 + q / 2, nu), rel=0.03)


def test_edges_shapes_and_refusals():
    coherence = np.array([[1.0, 0.0, 0.9], [0.5, 0.99, 1.0]])
    sigma = frf_random_error(coherence, np.array([10, 4, 1]))
    assert sigma.shape == (2, 3)
    assert sigma[0, 0] == 0.0 and np.isinf(sigma[0, 1]) and np.all(np.isnan(sigma[:, 2]))
    assert sigma[1, 0] == pytest.approx(1 / np.sqrt(18))  # gamma^2 = 0.5, 10 averages: sqrt(0.5 / (0.5 * 2 * 9))
    known = frf_random_error(coherence, np.array([10, 4, 1]), coherence_estimated=False)
    assert known[1, 0] == pytest.approx(1 / np.sqrt(20)) and known[0, 2] == pytest.approx(np.sqrt(0.1 / 1.8))
    for bad_coherence, bad_averages in ((1.2, 5), (-0.1, 5), (np.nan, 5), (0.9, 0), (0.9, 2.5)):
        with pytest.raises(ValueError):
            frf_random_error(bad_coherence, bad_averages)
