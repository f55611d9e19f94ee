"""Model-level invariants: matrices, parameter domain, FRF solvers, reciprocity, convergence."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core import Block, Material, build_model, mesh_blocks
from fe_core.assembly import SegmentedMatrix
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ

KRYLOV_VS_DIRECT_RTOL = 1e-8  # issue 2's accuracy target for the fast solver
RECIPROCITY_RTOL = 1e-9


def random_alphas(rng, n=4):
    return [rng.uniform(-0.95, 1.0, 6) for _ in range(n)]


def test_constrained_stiffness_is_symmetric_positive_definite(benchmark_model):
    K = benchmark_model.stiffness(ALPHA_ACTUAL)
    asym = abs(K - K.T).max()
    assert asym <= 1e-12 * abs(K).max()
    lowest = sp.linalg.eigsh(K, k=1, M=benchmark_model.mass(), sigma=0, which="LM")[0][0]
    assert lowest > 0


def test_stiffness_is_the_weighted_sum_of_segment_matrices(benchmark_model, rng):
    alpha = rng.uniform(-0.9, 1.0, 6)
    parts = benchmark_model.stiffness_segments
    explicit = sum((1 + alpha[i]) * parts.segment(i) for i in range(6))
    assert abs(benchmark_model.stiffness(alpha) - explicit).max() <= 1e-12 * abs(explicit).max()


def test_segmented_matrix_keeps_entries_that_cancel_in_the_sum():
    A = sp.csr_matrix(np.array([[1.0, 2.0], [0.0, 1.0]]))
    B = sp.csr_matrix(np.array([[1.0, -2.0], [0.0, 3.0]]))
    seg = SegmentedMatrix.from_matrices([A, B])
    np.testing.assert_allclose(seg.combine(np.array([2.0, 1.0])).toarray(), 2 * A.toarray() + B.toarray())


def test_mass_factors_scale_total_mass_segment_by_segment(benchmark_model):
    gamma = np.array([0.5, 0.0, 0.0, 0.0, 0.0, -0.5])
    masses = np.array(benchmark_model.segment_masses)
    expected = masses.sum() + 0.5 * masses[0] - 0.5 * masses[5]
    assert benchmark_model.total_mass(gamma) == pytest.approx(expected, rel=1e-12)
    assert masses[0] == pytest.approx(7850 * 0.115 * 0.14 * 0.01, rel=1e-12)


@pytest.mark.parametrize(
    ("alpha", "message"),
    [
        ([-0.5, -1.0, 0, 0, 0, 0], "alpha_2 = -1.0"),
        ([0, 0, -1.5, 0, 0, 0], "alpha_3 = -1.5"),
        ([0, 0, 0, np.nan, 0, 0], "alpha_4 = nan"),
        ([0, 0, 0, 0, np.inf, 0], "alpha_5 = inf"),
        ([0, 0, 0], "6 entries"),
    ],
)
def test_parameters_outside_the_domain_are_refused_by_name(benchmark_model, alpha, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        benchmark_model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ)


def test_mass_factor_outside_the_domain_is_refused_by_name(benchmark_model):
    with pytest.raises(ValueError, match="gamma_6 = -2.0"):
        benchmark_model.frf(ALPHA_ACTUAL, [100.0], gamma=[0, 0, 0, 0, 0, -2.0])


@pytest.mark.parametrize("freqs", [[], [-5.0], [0.0, 100.0], [np.nan]])
def test_bad_frequencies_are_refused(benchmark_model, freqs):
    with pytest.raises(ValueError, match="frequencies"):
        benchmark_model.frf(ALPHA_ACTUAL, freqs)


def test_krylov_frf_equals_direct_solve_over_the_domain(benchmark_model, rng):
    freqs = np.concatenate([MEASUREMENT_FREQUENCIES_HZ, [20.0, 150.0, 420.0, 600.0]])
    for alpha in [ALPHA_ACTUAL, np.zeros(6), *random_alphas(rng)]:
        fast = benchmark_model.frf(alpha, freqs)
        ref = benchmark_model.frf(alpha, freqs, method="direct")
        np.testing.assert_allclose(fast, ref, rtol=KRYLOV_VS_DIRECT_RTOL)


def test_krylov_frf_equals_direct_solve_with_mass_factors(benchmark_model, rng):
    gamma = rng.uniform(-0.5, 0.5, 6)
    fast = benchmark_model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, gamma=gamma)
    ref = benchmark_model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, gamma=gamma, method="direct")
    np.testing.assert_allclose(fast, ref, rtol=KRYLOV_VS_DIRECT_RTOL)


@pytest.mark.parametrize("method", ["direct", "krylov"])
def test_frf_matrix_is_reciprocal_and_sums_to_the_combined_load(benchmark_model, rng, method):
    alpha = rng.uniform(-0.9, 0.5, 6)
    H = benchmark_model.frf_matrix(alpha, MEASUREMENT_FREQUENCIES_HZ, method=method)
    assert H.shape == (12, 6, 6)
    np.testing.assert_allclose(H, H.transpose(0, 2, 1), rtol=RECIPROCITY_RTOL, atol=0)
    combined = benchmark_model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ, method=method)
    np.testing.assert_allclose(H.sum(axis=2), combined, rtol=KRYLOV_VS_DIRECT_RTOL)


def test_frf_at_low_frequency_tends_to_static_flexibility(benchmark_model):
    K = benchmark_model.stiffness(ALPHA_ACTUAL).tocsc()
    static = sp.linalg.spsolve(K, benchmark_model.combined_load())[benchmark_model.sensor_dofs]
    Z = benchmark_model.frf(ALPHA_ACTUAL, [1e-3])[0]
    np.testing.assert_allclose(Z.real, static, rtol=1e-6)


def clamped_strip(n_x: int, length=1.0, width=0.02, height=0.02):
    mesh = mesh_blocks(
        [Block(np.linspace(0, length, n_x + 1), np.array([-width / 2, width / 2]), np.array([0.0, height]), "strip")]
    )
    clamped = np.concatenate([mesh.nodes_where(x=0.0), mesh.nodes_where(x=length)])
    sensor = mesh.nearest_node([length / 2, width / 2, height])
    material = Material(2.06e11, 0.3, 7850.0)
    return build_model(mesh, material, {"strip": np.arange(mesh.n_cells)}, clamped, [sensor], (0.0, 0.0))


def test_clamped_strip_first_frequency_converges_to_euler_bernoulli():
    E, rho, L, b, h = 2.06e11, 7850.0, 1.0, 0.02, 0.02  # L/h = 50: shear deformation ~0.1 %
    f_eb = 4.730040745**2 / (2 * np.pi * L**2) * np.sqrt(E * b * h**3 / 12 / (rho * b * h))
    meshes = [8, 16, 32, 64]
    freqs = np.array([clamped_strip(n).natural_frequencies([0.0], 1)[0] for n in meshes])
    errors = np.abs(freqs / f_eb - 1.0)
    assert np.all(np.diff(errors) < 0), errors
    assert errors[-1] < 2e-3
    # Successive differences shrink by a steady factor: an asymptotic convergence rate.
    diffs = -np.diff(freqs)
    rates = np.log2(diffs[:-1] / diffs[1:])
    assert np.all(rates > 1.5), rates
