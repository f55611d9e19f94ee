"""Pearson correlation (Eq. 16), the exact FRF derivative, and the identifiability summary."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
from fe_core.solvers.sensitivity import frf_jacobian, identifiability, log_amplitude_jacobian, pearson_correlation


# -- Pearson correlation --------------------------------------------------------------------------
def test_pearson_matches_numpy_corrcoef_and_scipy_pearsonr(rng):
    X = rng.uniform(-1, 1, (500, 4))
    Y = np.column_stack([X[:, 0] + 0.3 * rng.normal(size=500), np.exp(X[:, 1]) * X[:, 2], rng.normal(size=500)])
    rho = pearson_correlation(X, Y)
    reference = np.corrcoef(X.T, Y.T)[:4, 4:]
    np.testing.assert_allclose(rho, reference, atol=1e-12)
    r, _ = stats.pearsonr(X[:, 0], Y[:, 0])
    assert rho[0, 0] == pytest.approx(r, abs=1e-12)


def test_parameter_that_cannot_influence_a_response_has_correlation_near_zero(rng):
    n = 10_000
    X = rng.uniform(-1, 1, (n, 3))
    # The response depends strongly (and non-linearly) on x1 and x2, not at all on x3.
    y = 1e-6 / ((1.2 + X[:, 0]) * (1.5 + 0.5 * X[:, 1]))
    rho = pearson_correlation(X, y)[:, 0]
    # Under independence rho is about N(0, 1/sqrt(n)): 5 standard deviations is 0.05.
    assert abs(rho[2]) < 5 / np.sqrt(n)
    assert rho[0] < -0.6 and rho[1] < -0.2


def test_pearson_is_scale_and_offset_invariant_and_keeps_precision_with_large_offsets(rng):
    X = rng.normal(size=(300, 2))
    y = X[:, 0] - 0.5 * X[:, 1] + rng.normal(size=300)
    base = pearson_correlation(X, y)
    shifted = pearson_correlation(1e8 + 3.0 * X, 1e-9 * (y + 1e3))
    np.testing.assert_allclose(shifted, base, atol=1e-7)


def test_pearson_of_a_constant_column_is_nan_and_bad_input_is_refused(rng):
    X = rng.normal(size=(50, 2))
    Y = np.column_stack([np.full(50, 3.2e-7), X[:, 0]])
    rho = pearson_correlation(X, Y)
    assert np.all(np.isnan(rho[:, 0])) and rho[0, 1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="samples"):
        pearson_correlation(X, Y[:-1])
    Y[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"Y\[4, 1\]"):
        pearson_correlation(X, Y)


# -- the exact derivative of the FE model ------------------------------------------------------------
def test_frf_derivative_matches_central_differences_of_the_direct_solver(benchmark_model):
    """Both methods: the Krylov projection (default) and the direct adjoint (reference)."""
    alpha = ALPHA_ACTUAL
    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]
    results = {method: frf_jacobian(benchmark_model, alpha, freqs, method=method) for method in ("krylov", "direct")}
    for Z, _ in results.values():
        np.testing.assert_allclose(Z, benchmark_model.frf(alpha, freqs, method="direct"), rtol=1e-9)
    h = 1e-4  # truncation ~h^2 and round-off ~1e-10/h both near 1e-6 of the derivative
    for i in range(benchmark_model.n_segments):
        e = np.zeros(benchmark_model.n_segments)
        e[i] = h
        fd = (benchmark_model.frf(alpha + e, freqs, method="direct")
              - benchmark_model.frf(alpha - e, freqs, method="direct")) / (2 * h)
        for method, (_, dZ) in results.items():
            assert np.abs(fd - dZ[:, :, i]).max() <= 1e-5 * np.abs(dZ[:, :, i]).max(), (method, i)


def test_log_amplitude_jacobian_is_the_derivative_of_log_abs_frf(benchmark_model):
    alpha = np.array([0.1, -0.2, 0.3, 0.0, -0.4, 0.2])
    freqs = MEASUREMENT_FREQUENCIES_HZ
    J = log_amplitude_jacobian(benchmark_model, alpha, freqs)
    assert J.shape == (freqs.size * benchmark_model.n_sensors, benchmark_model.n_segments)
    h = 1e-4
    for i in (0, 3):
        e = np.zeros(6)
        e[i] = h
        up = np.log(np.abs(benchmark_model.frf(alpha + e, freqs, method="direct"))).ravel()
        down = np.log(np.abs(benchmark_model.frf(alpha - e, freqs, method="direct"))).ravel()
        np.testing.assert_allclose(J[:, i], (up - down) / (2 * h), atol=1e-5 * np.abs(J[:, i]).max())


def test_the_jacobian_of_updated_mass_factors_matches_central_differences(benchmark_model):
    """Mass factors of segments 2 and 5 updated too: their columns against differences of the direct solver
    driven by gamma explicitly (not through the parameter vector)."""
    import dataclasses

    model = dataclasses.replace(benchmark_model, mass_parameters=[1, 4])
    assert model.parameter_names[6:] == ["gamma_2", "gamma_5"]
    theta = np.concatenate([ALPHA_ACTUAL, [0.2, -0.1]])
    gamma = np.array([0, 0.2, 0, 0, -0.1, 0])
    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]
    Z, dZ = frf_jacobian(model, theta, freqs)
    assert dZ.shape == (4, 6, 8)
    np.testing.assert_allclose(Z, benchmark_model.frf(ALPHA_ACTUAL, freqs, gamma, method="direct"), rtol=1e-9)
    h = 1e-4
    for k, seg in ((6, 1), (7, 4)):
        e = np.zeros(6)
        e[seg] = h
        fd = (benchmark_model.frf(ALPHA_ACTUAL, freqs, gamma + e, method="direct")
              - benchmark_model.frf(ALPHA_ACTUAL, freqs, gamma - e, method="direct")) / (2 * h)
        assert np.abs(fd - dZ[:, :, k]).max() <= 1e-5 * np.abs(dZ[:, :, k]).max(), k
    with pytest.raises(ValueError, match="8 entries"):
        frf_jacobian(model, ALPHA_ACTUAL, freqs)  # the parameter vector, not alpha alone


def test_frf_jacobian_refuses_parameters_outside_the_domain(benchmark_model):
    with pytest.raises(ValueError, match="alpha_2"):
        frf_jacobian(benchmark_model, [0, -1.0, 0, 0, 0, 0], [100.0])


# -- identifiability ------------------------------------------------------------------------------
def test_identifiability_std_equals_the_inverse_normal_matrix(rng):
    J = rng.normal(size=(72, 6)) * np.array([5.0, 3.0, 1.0, 0.5, 0.2, 2.0])
    result = identifiability(J, noise=0.01, tolerance=0.05)
    reference = 0.01 * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    np.testing.assert_allclose(result.std, reference, rtol=1e-10)
    np.testing.assert_allclose(result.singular_values, np.linalg.svd(J, compute_uv=False), rtol=1e-12)
    np.testing.assert_array_equal(result.identifiable, reference <= 0.05)


def test_a_parameter_the_sensors_cannot_see_is_reported_unidentifiable(rng):
    J = rng.normal(size=(40, 3))
    J[:, 1] = 0.0  # no response depends on the second parameter
    result = identifiability(J, names=["a", "b", "c"])
    assert result.singular_values[-1] <= 1e-12 * result.singular_values[0]
    assert list(result.identifiable) == [True, False, True]
    assert np.isinf(result.std[1]) and np.all(np.isfinite(result.std[[0, 2]]))
    assert result.describe_direction(2) == "1.00 b"
    assert any(line.startswith("b: can NOT") for line in result.summary_lines())


def test_two_parameters_acting_alike_give_a_weak_difference_direction(rng):
    J = rng.normal(size=(40, 3))
    J[:, 2] = J[:, 1] * (1 + 1e-4)  # the sensors see b and c only through their sum
    result = identifiability(J, names=["a", "b", "c"], noise=0.01, tolerance=0.05)
    weakest = result.directions[-1]
    np.testing.assert_allclose(np.abs(weakest), [0, 1 / np.sqrt(2), 1 / np.sqrt(2)], atol=1e-3)
    assert weakest[1] * weakest[2] < 0
    assert list(result.identifiable) == [True, False, False]
    assert result.condition_number > 1e3


def test_frf_jacobian_of_channels_under_two_references_is_the_channels_frf_and_the_direct_derivative():
    """Channels of two references: Z equals ``frf_channels`` (Krylov, 1e-9) and dZ the direct per-frequency
    derivative (one space carries both loads)."""
    from tasks.problem import read_model_ref

    model = read_model_ref("three_plate")[0]  # the benchmark's file: excitations "combined" and "hammer"
    freqs, theta = np.array([100.0, 120.0, 290.0]), np.full(6, -0.2)
    channels = (np.array([0, 2, 4, 1, 5]), np.array([0, 1, 1, 0, 1]))
    Z, dZ = frf_jacobian(model, theta, freqs, channels=channels)
    Zc = model.parameter_frf(theta, freqs, channels, method="direct")
    assert Z.shape == (3, 5) and dZ.shape == (3, 5, 6)
    assert np.abs(Z - Zc).max() <= 1e-9 * np.abs(Zc).max()
    Zd, dZd = frf_jacobian(model, theta, freqs, channels=channels, method="direct")
    assert np.abs(dZ - dZd).max() <= 1e-8 * np.abs(dZd).max()
