"""The FRF derivatives on a Krylov space (fe_core.solvers.frf_derivatives) against the direct adjoint and
central differences: the benchmark, a tet10 model file, the matrices example, general directions."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.solvers import frf
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
from fe_core.solvers.frf_derivatives import Direction, direct_frf_derivatives, krylov_frf_derivatives
from fe_core.io import read_model
from fe_core.solvers.sensitivity import frf_jacobian, log_amplitude_jacobian

REPO = Path(__file__).resolve().parents[2]
#: Both methods are exact to round-off times the conditioning: the FE core promises 1e-9 of a
#: frequency's largest response between methods on the benchmark and reaches 1.7e-9 on the
#: matrices example near its first modes; 1e-8 is the bound the Krylov tests use elsewhere.
#: The derivative's stopping test is 1e-8 of a direction's largest (frequency-scaled) derivative.
FRF_RTOL = 1e-8
DERIVATIVE_RTOL = 1e-8
#: Central differences of step 1e-4: truncation ~h^2 and round-off ~1e-10 / h, both ~1e-6.
FD_STEP = 1e-4
FD_RTOL = 1e-5


def _agree(model, alpha, freqs):
    """Krylov and direct Jacobians of a model agree to the methods' tolerances; returns the Krylov info."""
    Z, dZ, info = frf_jacobian(model, alpha, freqs, return_info=True)
    Zd, dZd = frf_jacobian(model, alpha, freqs, method="direct")
    assert info.converged, info
    size = np.abs(Zd).max(axis=1, keepdims=True)  # per frequency
    assert np.all(np.abs(Z - Zd) <= FRF_RTOL * size)
    # Per direction, relative to its largest derivative (each frequency scaled by its largest response).
    scaled = np.abs(dZ - dZd) / size[:, :, None]
    top = (np.abs(dZd) / size[:, :, None]).max(axis=(0, 1))
    assert np.all(scaled.max(axis=(0, 1)) <= 10 * DERIVATIVE_RTOL * top), scaled.max(axis=(0, 1)) / top
    return info


def _central_log_jacobian(model, alpha, freqs, i):
    e = np.zeros(model.n_segments)
    e[i] = FD_STEP
    up = np.log(np.abs(model.frf(alpha + e, freqs, method="direct"))).ravel()
    down = np.log(np.abs(model.frf(alpha - e, freqs, method="direct"))).ravel()
    return (up - down) / (2 * FD_STEP)


def test_benchmark_krylov_jacobian_equals_the_direct_adjoint(benchmark_model):
    """(Central differences of the benchmark's Krylov Jacobian: tests/fe_core/test_sensitivity.py.)"""
    info = _agree(benchmark_model, ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ)
    # Both the load and the six sensors' adjoints in one space: the load is the sum of the outputs,
    # so the starting block has rank 6 and every block step adds 6 vectors.
    assert info.dimension % 6 == 0 and info.dimension <= 96


def test_log_amplitude_jacobian_returns_the_frf_it_used(benchmark_model):
    alpha = np.array([0.1, -0.2, 0.3, 0.0, -0.4, 0.2])
    J, Z = log_amplitude_jacobian(benchmark_model, alpha, MEASUREMENT_FREQUENCIES_HZ, return_frf=True)
    Zd = benchmark_model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ, method="direct")
    assert np.all(np.abs(Z - Zd) <= FRF_RTOL * np.abs(Zd).max(axis=1, keepdims=True))
    assert J.shape == (Z.size, 6)


@pytest.fixture(scope="module")
def tet_model(tmp_path_factory, box_model_writer):
    """The tet10 cantilever model file (a remainder, a sensor along a vector, a two-DOF excitation)."""
    return read_model(box_model_writer(tmp_path_factory.mktemp("box") / "box"))


def _around_modes(model, n=3):
    f = model.natural_frequencies(np.zeros(model.n_segments), n)
    return np.sort(np.concatenate([0.97 * f, 1.02 * f]))


def test_tet10_model_file_jacobian_equals_direct_and_central_differences(tet_model):
    alpha = np.array([0.2, -0.3])
    freqs = _around_modes(tet_model)
    _agree(tet_model, alpha, freqs)
    J = log_amplitude_jacobian(tet_model, alpha, freqs)
    for i in range(2):
        np.testing.assert_allclose(J[:, i], _central_log_jacobian(tet_model, alpha, freqs, i),
                                   atol=FD_RTOL * np.abs(J[:, i]).max())


def test_matrices_model_jacobian_equals_direct():
    model = read_model(REPO / "data" / "examples" / "cantilever_matrices" / "model.toml")
    _agree(model, np.array([0.1, -0.2, 0.3, -0.1]), _around_modes(model, 4))


def test_mass_and_damping_directions_match_central_differences_of_the_direct_frf(tet_model):
    """dM, da, db and a mixed direction: the reduced model's derivative of every term of dD."""
    K = tet_model.stiffness(np.array([0.1, 0.0]))
    M = tet_model.mass()
    a, b = tet_model.damping
    F, L = tet_model.combined_load(), tet_model.outputs
    seg_m = tet_model.mass_segments.segment(1)
    dirs = [Direction(mass=seg_m), Direction(damping_a=1.0), Direction(damping_b=1e-6),
            Direction(stiffness=tet_model.stiffness_segments.segment(0), mass=0.5 * seg_m, damping_b=2e-7)]
    omegas = frf.hz_to_rad(_around_modes(tet_model))
    Z, dZ = krylov_frf_derivatives(K, M, a, b, F, L, dirs, omegas)
    Zd, dZd = direct_frf_derivatives(K, M, a, b, F, L, dirs, omegas)
    size = np.abs(Zd).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(Z - Zd) <= FRF_RTOL * size)

    def reading(K_, M_, a_, b_):
        z = frf.direct_frf(K_, M_, a_ * M_ + b_ * K_, F, omegas, np.arange(K.shape[0]))[:, :, 0]
        return z @ L.toarray()

    for i, d in enumerate(dirs):
        # A step that changes Z by 1e-4 of its size, not one of the direction's own size: the a-term
        # barely acts here (|dZ/da| is 1.5 % of |Z|), and a unit step of 1e-4 in a left its central
        # difference to the direct solve's round-off (err 4e-6 of |dZ| with OpenBLAS's Haswell kernels,
        # 7e-5 with its SkylakeX ones). Scaled, every direction's truncation and round-off are ~1e-6.
        h = 1e-4 * np.abs(Zd).max() / np.abs(dZd[..., i]).max()
        dk = d.stiffness if d.stiffness is not None else sp.csr_matrix(K.shape)
        dm = d.mass if d.mass is not None else sp.csr_matrix(K.shape)
        up = reading(K + h * dk, M + h * dm, a + h * d.damping_a, b + h * d.damping_b)
        down = reading(K - h * dk, M - h * dm, a - h * d.damping_a, b - h * d.damping_b)
        fd = (up - down) / (2 * h)
        err = np.abs(dZ[:, :, 0, i] - fd).max()
        assert err <= FD_RTOL * np.abs(fd).max(), (i, err / np.abs(fd).max())
        assert np.abs(dZ[..., i] - dZd[..., i]).max() <= 10 * DERIVATIVE_RTOL * np.abs(dZd[..., i]).max()


def test_an_explicit_shift_uses_the_indefinite_factorisation_and_agrees(benchmark_model):
    K, M = benchmark_model.stiffness(ALPHA_ACTUAL), benchmark_model.mass()
    a, b = benchmark_model.damping
    dirs = [Direction(stiffness=benchmark_model.stiffness_segments.segment(i)) for i in (1, 4)]
    omegas = frf.hz_to_rad(MEASUREMENT_FREQUENCIES_HZ[::3])
    args = (K, M, a, b, benchmark_model.combined_load(), benchmark_model.outputs, dirs, omegas)
    Z, dZ, info = krylov_frf_derivatives(*args, sigma=float(omegas[2] ** 2), return_info=True)
    Zd, dZd = direct_frf_derivatives(*args)
    assert info.converged and info.sigma > 0
    assert np.abs(Z - Zd).max() <= FRF_RTOL * np.abs(Zd).max()
    assert np.abs(dZ - dZd).max() <= 10 * DERIVATIVE_RTOL * np.abs(dZd).max()


def test_an_unconverged_space_falls_back_to_the_direct_solver(benchmark_model, caplog):
    K, M = benchmark_model.stiffness(ALPHA_ACTUAL), benchmark_model.mass()
    a, b = benchmark_model.damping
    dirs = [Direction(stiffness=benchmark_model.stiffness_segments.segment(0))]
    omegas = frf.hz_to_rad(MEASUREMENT_FREQUENCIES_HZ[:2])
    args = (K, M, a, b, benchmark_model.combined_load(), benchmark_model.outputs, dirs, omegas)
    with caplog.at_level(logging.WARNING, logger="fe_core.solvers.frf_derivatives"):
        Z, dZ, info = krylov_frf_derivatives(*args, max_dimension=12, return_info=True)
    assert not info.converged and "falling back" in caplog.text
    Zd, dZd = direct_frf_derivatives(*args)
    np.testing.assert_array_equal(Z, Zd)
    np.testing.assert_array_equal(dZ, dZd)


def test_unknown_method_is_refused(benchmark_model):
    with pytest.raises(ValueError, match="method"):
        frf_jacobian(benchmark_model, ALPHA_ACTUAL, [100.0], method="adjoint")
