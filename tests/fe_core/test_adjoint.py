"""The FRF and its derivatives from one Krylov space (fe_core.solvers.adjoint) against the direct solver."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.solvers.adjoint import ReducedResponse
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
from fe_core.solvers.frf import direct_frf, hz_to_rad

FREQS = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 9]]
#: The Krylov space converges the responses to 1e-10 of the largest per frequency; the direct
#: solve is exact to round-off: 1e-8 covers both on the benchmark's smallest amplitudes.
FRF_RTOL = 1e-8
#: Central differences with relative steps of 1e-4 on quantities curved on the scale of the
#: resonance: truncation error about 1e-7 of the derivative's size.
DIFF_RTOL = 1e-5


def _matrices(model):
    K, M = model.stiffness(ALPHA_ACTUAL), model.mass()
    a, b = model.damping
    return K, M, a, b


def _log_amplitude(model, K, M, a, b, gain=None):
    Z = direct_frf(K, M, a * M + b * K, model.combined_load(), hz_to_rad(FREQS), np.arange(K.shape[0]))[:, :, 0]
    amp = np.abs(model.read_outputs(Z))
    return np.log(amp * (1.0 + (0 if gain is None else gain))[None, :])


def test_the_reduced_frf_equals_the_direct_solve(benchmark_model):
    K, M, a, b = _matrices(benchmark_model)
    red = ReducedResponse(K, M, a, b, benchmark_model.combined_load(), benchmark_model.outputs, hz_to_rad(FREQS))
    ref = benchmark_model.frf(ALPHA_ACTUAL, FREQS, method="direct")
    assert red.info.converged
    assert np.max(np.abs(red.Z - ref)) <= FRF_RTOL * np.max(np.abs(ref))


def _exact_dlog(model, K, M, a, b, dK=None, dM=None, da=0.0, db=0.0):
    """``d ln|Z|`` from the adjoint formula with full fields of complex LU solves (the reference)."""
    w = hz_to_rad(FREQS)
    loads = np.column_stack([model.combined_load(), model.sensor_loads()])
    H = direct_frf(K, M, a * M + b * K, loads, w, np.arange(K.shape[0]))  # (p, n, 1 + n_s)
    h, X = H[:, :, 0], H[:, :, 1:]
    Z = model.read_outputs(h)
    dZ = np.zeros(Z.shape, dtype=complex)
    for p, wp in enumerate(w):
        dD = sp.csr_matrix(K.shape)
        if dK is not None:
            dD = dD + (1.0 + 1j * wp * b) * dK
        if dM is not None:
            dD = dD + (-(wp**2) + 1j * wp * a) * dM
        v = dD @ h[p] + 1j * wp * (da * (M @ h[p]) + db * (K @ h[p]))
        dZ[p] = -X[p].T @ v
    return np.real(dZ / Z)


#: The Krylov space converges the sensor responses to 1e-10 of the largest; the fields inside it
#: then give derivatives within 8e-10 of the largest (200 random DOFs measured): 1e-8.
ADJOINT_RTOL = 1e-8


@pytest.mark.parametrize("change", ["segment", "mass_node", "spring_node", "damping_a", "damping_b"])
def test_every_kind_of_change_has_the_derivative_of_the_exact_adjoint(benchmark_model, change):
    model = benchmark_model
    K, M, a, b = _matrices(model)
    red = ReducedResponse(K, M, a, b, model.combined_load(), model.outputs, hz_to_rad(FREQS))
    n = model.n_dofs
    unit = sp.csr_matrix(([1.0], ([700], [700])), shape=(n, n))  # a DOF far from every sensor
    args = {"segment": dict(dK=model.stiffness_segments.segment(3)), "mass_node": dict(dM=unit),
            "spring_node": dict(dK=unit), "damping_a": dict(da=1.0), "damping_b": dict(db=1.0)}[change]
    exact = _exact_dlog(model, K, M, a, b, **args)
    assert np.max(np.abs(red.dlog(**args) - exact)) <= ADJOINT_RTOL * np.max(np.abs(exact))


def test_the_adjoint_derivative_is_the_central_difference_of_the_direct_frf(benchmark_model):
    """The formula itself (a segment's stiffness and a sensor gain) against differences of direct solves."""
    model = benchmark_model
    K, M, a, b = _matrices(model)
    gain = np.array([0.0, 0.02, 0.0, 0.0, -0.03, 0.0])
    red = ReducedResponse(K, M, a, b, model.combined_load(), model.outputs, hz_to_rad(FREQS), gain)
    dK, dg, h = model.stiffness_segments.segment(3), np.eye(6)[4], 1e-4
    fd = (_log_amplitude(model, K + h * dK, M, a, b, gain + h * dg)
          - _log_amplitude(model, K - h * dK, M, a, b, gain - h * dg)) / (2 * h)
    assert np.max(np.abs(red.dlog(dK=dK, dgain=dg) - fd)) <= DIFF_RTOL * np.max(np.abs(fd))


@pytest.mark.parametrize("chunk", [256, 2])
@pytest.mark.parametrize("per_location", [3, 1, 0])
def test_diagonal_changes_at_many_nodes_at_once_equal_one_by_one(benchmark_model, monkeypatch, chunk, per_location):
    """The batch product of the screening (every point mass or spring at once) against dlog per change, in one
    block and in blocks of two locations (a DOF shared by locations of two blocks, a location of padding only, and
    locations of no DOF at all: a sensor mass whose sensors' nodes the model does not hold crashed the screen)."""
    import fe_core.solvers.adjoint as adjoint

    monkeypatch.setattr(adjoint, "DIAGONAL_CHUNK", chunk)
    model = benchmark_model
    K, M, a, b = _matrices(model)
    red = ReducedResponse(K, M, a, b, model.combined_load(), model.outputs, hz_to_rad(FREQS))
    n = model.n_dofs
    rows = np.array([[10, 11, 12], [400, -1, 401], [n - 1, -1, -1], [-1, -1, -1], [11, 400, -1]])[:, :per_location]
    for matrix in ("mass", "stiffness"):
        batch = red.diagonal_dlog(matrix, rows)
        assert batch.shape == (len(rows), FREQS.size, model.outputs.shape[1])
        for k, r in enumerate(rows):
            r = r[r >= 0]
            D = sp.csr_matrix((np.ones(r.size), (r, r)), shape=(n, n))
            one = red.dlog(dM=D) if matrix == "mass" else red.dlog(dK=D)
            assert np.max(np.abs(batch[k] - one)) <= 1e-10 * np.max(np.abs(one))
