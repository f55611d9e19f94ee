"""The FRF solvers on an unstructured numbering: the sparse Cholesky path of krylov_frf."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.solvers import frf
from fe_core.assembly import assemble, free_dof_map
from fe_core.elements import tet10
from fe_core.material import isotropic_elasticity
from fe_core.tet_mesh import box_tets

E, NU, RHO = 7.0e10, 0.33, 2700.0
DAMPING = (5.0, 2e-6)


def scrambled_block(cells_per_side, rng):
    """A 0.3 x 0.2 x 0.04 m tet10 block whose nodes are numbered at random (bandwidth far
    above frf.MAX_BANDWIDTH, as gmsh meshes are): nodes and unconstrained K and M."""
    nodes, cells = box_tets((0.3, 0.2, 0.04), cells_per_side, order=2)
    order = rng.permutation(len(nodes))
    nodes, cells = nodes[np.argsort(order)], order[cells]
    n = 3 * len(nodes)
    dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(len(cells), -1)
    K = assemble(tet10.element_stiffness(nodes[cells], isotropic_elasticity(E, NU)), dofs, n)
    M = assemble(tet10.element_mass(nodes[cells], RHO), dofs, n)
    return nodes, K, M


@pytest.fixture(scope="module")
def scrambled_plate():
    """The block clamped at x = 0: K and M on the free DOFs, two loads and five outputs."""
    rng = np.random.default_rng(5)
    nodes, K, M = scrambled_block((6, 4, 2), rng)
    free = free_dof_map(K.shape[0], np.flatnonzero(np.repeat(nodes[:, 0] < 1e-12, 3)))
    K, M = K[free][:, free].tocsr(), M[free][:, free].tocsr()
    F = np.zeros((free.size, 2))
    F[rng.choice(free.size, 2, replace=False), [0, 1]] = 1.0
    out = rng.choice(free.size, 5, replace=False)
    return K, M, F, out


def test_scrambled_numbering_defeats_the_banded_path(scrambled_plate):
    K = sp.coo_matrix(scrambled_plate[0])
    assert np.max(K.col - K.row) > frf.MAX_BANDWIDTH


def test_krylov_on_the_sparse_cholesky_equals_the_direct_solve(scrambled_plate, monkeypatch):
    K, M, F, out = scrambled_plate
    calls = []
    real = frf.spd_solver
    monkeypatch.setattr(frf, "spd_solver", lambda A: calls.append(A.shape) or real(A))
    omegas = frf.hz_to_rad(np.linspace(20.0, 900.0, 12))
    fast, info = frf.krylov_frf(K, M, *DAMPING, F, omegas, out, return_info=True)
    ref = frf.direct_frf(K, M, DAMPING[0] * M + DAMPING[1] * K, F, omegas, out)
    assert calls == [K.shape]
    assert info.converged and info.sigma == 0.0, info
    # Both are exact to round-off times the conditioning; 1e-8 is the Krylov stopping test's.
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_spd_solver_solves_and_refuses_an_indefinite_matrix(scrambled_plate, rng):
    K, M, _, _ = scrambled_plate
    solve = frf.spd_solver(K)
    rhs = rng.normal(size=(K.shape[0], 3))
    x = solve(rhs)
    assert x.shape == rhs.shape and solve(rhs[:, 0]).shape == (K.shape[0],)
    assert np.linalg.norm(K @ x - rhs) < 1e-10 * np.linalg.norm(rhs)
    assert frf.spd_solver(K - 1e8 * M) is None  # past the first three eigenvalues (5.6e6 ... 8.2e7)


def test_an_explicit_shift_factors_the_indefinite_pencil_with_superlu(scrambled_plate):
    K, M, F, out = scrambled_plate
    omegas = frf.hz_to_rad([300.0, 500.0])
    # K - 1e7 M is indefinite: the first eigenvalue of (K, M) is 5.6e6 rad^2/s^2 (377 Hz).
    fast, info = frf.krylov_frf(K, M, *DAMPING, F, omegas, out, sigma=1e7, return_info=True)
    ref = frf.direct_frf(K, M, DAMPING[0] * M + DAMPING[1] * K, F, omegas, out)
    assert info.sigma == 1e7
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_unsupported_structure_falls_back_to_the_shifted_superlu():
    # Free-free: K has six rigid-body modes, PARDISO's Cholesky refuses it, and the Krylov
    # FRF factors K - sigma M at the centre of the band instead.
    _, K, M = scrambled_block((4, 3, 1), np.random.default_rng(6))
    assert frf.spd_solver(K) is None
    F = np.zeros((K.shape[0], 1))
    F[5, 0] = 1.0
    omegas = frf.hz_to_rad(np.linspace(200.0, 2000.0, 6))
    fast, info = frf.krylov_frf(K, M, *DAMPING, F, omegas, np.array([5, 100]), return_info=True)
    ref = frf.direct_frf(K, M, DAMPING[0] * M + DAMPING[1] * K, F, omegas, np.array([5, 100]))
    assert info.sigma == pytest.approx(omegas.min() * omegas.max())
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
