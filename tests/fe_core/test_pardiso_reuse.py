"""The reused PARDISO work of fe_core.solvers.pardiso (issue 28) solves what a fresh factorisation solves.

References: SuperLU (scipy) on the same matrices; for the closure's screen, central differences of the
direct complex solver; for the FRF, the plain path (a new PARDISO solver per matrix).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fe_core.assembly import assemble, free_dof_map
from fe_core.elements import tet10
from fe_core.material import isotropic_elasticity
from fe_core.solvers import adjoint, frf, pardiso
from fe_core.tet_mesh import box_tets

RTOL = 1e-10  # a Cholesky solve of a matrix of condition ~1e6 agrees with LU to ~1e-10 or better


@pytest.fixture(scope="module")
def block():
    """A tet10 block clamped at x = 0, nodes numbered at random (PARDISO's path, as a gmsh mesh): K, M, split
    in two 'segments' (x below and above 0.15 m), one load, four outputs."""
    rng = np.random.default_rng(11)
    nodes, cells = box_tets((0.3, 0.2, 0.04), (5, 3, 2), order=2)
    order = rng.permutation(len(nodes))
    nodes, cells = nodes[np.argsort(order)], order[cells]
    n = 3 * len(nodes)
    dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(len(cells), -1)
    left = nodes[cells[:, :4]].mean(axis=1)[:, 0] < 0.15
    D = isotropic_elasticity(7e10, 0.33)
    Ks = [assemble(tet10.element_stiffness(nodes[cells[s]], D), dofs[s], n) for s in (left, ~left)]
    M = assemble(tet10.element_mass(nodes[cells], 2700.0), dofs, n)
    free = free_dof_map(n, np.flatnonzero(np.repeat(nodes[:, 0] < 1e-12, 3)))
    Ks = [k[free][:, free].tocsr() for k in Ks]
    M = M[free][:, free].tocsr()
    F = np.zeros(free.size)
    F[rng.integers(free.size)] = 1.0
    out = rng.choice(free.size, 4, replace=False)
    return Ks, M, F, out


def stiffness(Ks, alpha):
    """K(alpha) on one pattern (the segments' sum keeps every index, as the model's assembly does)."""
    K = (1 + alpha[0]) * Ks[0] + (1 + alpha[1]) * Ks[1]
    return sp.csr_matrix(K)


def lu_solve(K, rhs):
    return spla.splu(sp.csc_matrix(K)).solve(rhs)


def close(x, ref):
    return np.max(np.abs(x - ref)) / np.max(np.abs(ref))


def test_analysis_and_factor_reused_woodbury_for_a_few_rows(block):
    Ks, M, F, out = block
    pardiso.clear()
    rhs = np.random.default_rng(0).standard_normal((Ks[0].shape[0], 3))
    K0 = stiffness(Ks, [0.1, -0.2])
    s0 = pardiso.cholesky(K0)
    assert close(s0(rhs), lu_solve(K0, rhs)) < RTOL
    # The same values again: no factorisation.
    s0b = pardiso.cholesky(K0.copy())
    assert close(s0b(rhs[:, 0]), lu_solve(K0, rhs[:, 0])) < RTOL
    assert pardiso.stats["factorisations"] == 1 and pardiso.stats["reused"] == 1
    # A grounded spring at one DOF and a 3 x 3 coupling (a spring between two nodes' DOFs): Woodbury.
    n = K0.shape[0]
    dK = sp.lil_matrix((n, n))
    dK[7, 7] = 3e7
    j20 = int(K0.indices[K0.indptr[20] + 3])  # a DOF coupled to DOF 20: the change stays on K0's pattern
    assert j20 != 20
    for i, j, v in [(20, 20, 1e6), (j20, j20, 1e6), (20, j20, -1e6)]:
        dK[i, j] += v
        if i != j:
            dK[j, i] += v
    K1 = sp.csr_matrix(K0 + dK.tocsr())
    s1 = pardiso.cholesky(K1)
    assert pardiso.stats["woodbury"] == 1 and pardiso.stats["factorisations"] == 1
    assert close(s1(rhs), lu_solve(K1, rhs)) < RTOL
    # A change outside K0's pattern (a spring between two DOFs no element couples; sparse sums also drop
    # explicit zeros): still Woodbury on K0's factor.
    far = int(np.setdiff1d(np.arange(n), K0.indices[K0.indptr[5]:K0.indptr[6]])[-1])
    tie = sp.csr_matrix(([2e6, 2e6, -2e6, -2e6], ([5, far, 5, far], [5, far, far, 5])), shape=(n, n))
    K3 = sp.csr_matrix(K0 + tie)
    s3 = pardiso.cholesky(K3)
    assert pardiso.stats["woodbury"] == 2 and pardiso.stats["factorisations"] == 1
    assert close(s3(rhs), lu_solve(K3, rhs)) < RTOL
    # Other factors: a new numerical factorisation on the analysed pattern, no second analysis.
    del s0, s0b, s1, s3
    K2 = stiffness(Ks, [-0.3, 0.4])
    s2 = pardiso.cholesky(K2)
    assert close(s2(rhs), lu_solve(K2, rhs)) < RTOL
    assert pardiso.stats["factorisations"] == 2 and pardiso.stats["analyses"] == 1
    # Not positive-definite: None, as the plain path.
    assert pardiso.cholesky(-K2) is None


def test_krylov_frf_on_reused_factors_equals_the_plain_path(block, monkeypatch):
    Ks, M, F, out = block
    w = 2 * np.pi * np.array([200.0, 900.0, 2500.0])
    K = stiffness(Ks, [0.2, 0.1])
    n = K.shape[0]
    spring = sp.csr_matrix(([5e6], ([30], [30])), shape=(n, n))
    cases = [K, sp.csr_matrix(K + spring)]
    monkeypatch.setattr(pardiso, "ENABLED", False)
    plain = [frf.krylov_frf(k, M, 5.0, 2e-6, F, w, out) for k in cases]
    monkeypatch.setattr(pardiso, "ENABLED", True)
    pardiso.clear()
    fast = [frf.krylov_frf(k, M, 5.0, 2e-6, F, w, out) for k in cases]
    assert pardiso.stats["woodbury"] == 1
    direct = [frf.direct_frf(k, M, 5.0 * M + 2e-6 * k, F, w, out) for k in cases]
    for p, f, d in zip(plain, fast, direct):
        assert close(f, p) < 1e-9  # both converged Krylov spaces (1e-10 rtol) of the same operator
        assert close(f, d) < 1e-8


def test_adjoint_screen_equals_central_differences(block):
    """d ln|Z| of a point mass at three DOF triples from one reduced response (on the pooled factor)
    against central differences of the direct complex solve."""
    Ks, M, F, out = block
    K = stiffness(Ks, [0.0, 0.0])
    w = 2 * np.pi * np.array([300.0, 1500.0])
    L = sp.csc_matrix((np.ones(out.size), (out, np.arange(out.size))), shape=(K.shape[0], out.size))
    pardiso.clear()
    red = adjoint.ReducedResponse(K, M, 5.0, 2e-6, F, L, w)
    rows = np.array([[3, 4, 5], [60, 61, 62], [300, 301, 302]])
    screened = red.diagonal_dlog("mass", rows)  # (3, p, s)
    h = 1e-4  # kg: a small fraction of the block's mass (6.5 kg); the difference error ~h^2
    for k, r in enumerate(rows):
        dM = sp.csr_matrix((np.ones(3), (r, r)), shape=K.shape)
        zp, zm = (frf.direct_frf(K, M + s * dM, 5.0 * (M + s * dM) + 2e-6 * K, F, w, out)[:, :, 0]
                  for s in (h, -h))
        fd = (np.log(np.abs(zp)) - np.log(np.abs(zm))) / (2 * h)
        assert np.max(np.abs(screened[k] - fd)) < 1e-6 * max(1.0, np.max(np.abs(fd)))


def test_nearby_matrix_solved_by_cg_on_the_held_factor(block, monkeypatch):
    """K at nearby segment factors: CG preconditioned by the held factor (no factorisation) while within the
    budget, else refactored in place; either way the solution of a fresh LU to round-off."""
    from fe_core.solvers import nearby

    Ks, M, F, out = block
    monkeypatch.setattr(pardiso, "NEARBY_MIN_NNZ", 0)
    monkeypatch.setattr(nearby, "pcg_budget", lambda *a: 6)
    pardiso.clear()
    rhs = np.random.default_rng(1).standard_normal((Ks[0].shape[0], 4))
    base = pardiso.cholesky(stiffness(Ks, [0.1, -0.2]))
    del base  # idle, holding its factor
    K1 = stiffness(Ks, [0.1 + 1e-3, -0.2 - 2e-3])
    s1 = pardiso.cholesky(K1)
    x1 = s1(rhs)
    assert pardiso.stats["nearby"] == 1 and pardiso.stats["factorisations"] == 1
    assert pardiso.stats["nearby_refactored"] == 0 and pardiso.stats["pcg_solves"] <= 6 * rhs.shape[1]
    assert close(x1, lu_solve(K1, rhs)) < RTOL
    del s1
    # Far away: 6 solves do not reach the tolerance; the factor is renewed and the solve is direct.
    K2 = stiffness(Ks, [0.9, -0.6])
    s2 = pardiso.cholesky(K2)
    x2 = s2(rhs)
    assert pardiso.stats["nearby"] == 2 and pardiso.stats["nearby_refactored"] == 1
    assert pardiso.stats["factorisations"] == 2 and pardiso.stats["analyses"] == 1
    assert close(x2, lu_solve(K2, rhs)) < RTOL
    assert close(s2(rhs[:, 0]), lu_solve(K2, rhs[:, 0])) < RTOL  # later calls on the new factor


def test_budget_from_the_operation_counts():
    """CG pays only while its extra solves cost less than a factorisation: (k - 1) rhs solve <= factor."""
    from fe_core.solvers.nearby import FACTOR_RATE, MAX_PCG_SOLVES, SOLVE_RATE, pcg_budget

    nnz_l, rhs = 10**8, 60
    solve = 4 * nnz_l / SOLVE_RATE  # seconds per right-hand side
    for extra in (0, 1, 2, 5):  # a factorisation worth exactly `extra` more solves of every right-hand side
        mflop = (extra * rhs * solve + 1e-3) * FACTOR_RATE / 1e6
        assert pcg_budget(mflop, nnz_l, rhs) == min(MAX_PCG_SOLVES, 1 + extra)
    assert pcg_budget(0.0, nnz_l, rhs) == 0
    assert pcg_budget(1e9, nnz_l, rhs) == MAX_PCG_SOLVES


def test_factor_on_fewer_threads_than_its_analysis_does_not_crash(block):
    """PARDISO (MKL 2026.2) crashes in a numerical factorisation on fewer threads than its analysis ran on:
    the pool keeps a handle per thread count, and each handle runs every phase on its own."""
    Ks, M, F, out = block
    pardiso.clear()
    rhs = np.ones(Ks[0].shape[0])
    with pardiso.threads(2):
        s = pardiso.cholesky(stiffness(Ks, [0.0, 0.0]))
    del s
    K = stiffness(Ks, [0.3, 0.2])
    s = pardiso.cholesky(K)  # outside: the flows' one thread
    assert close(s(rhs), lu_solve(K, rhs)) < RTOL
    with pardiso.threads(2):
        assert close(s(rhs), lu_solve(K, rhs)) < RTOL  # a solve inside another setting: the handle's own


def test_a_solution_written_into_a_column_major_block_is_the_returned_one(block):
    """``solve(rhs, out=...)`` writes ``A^-1 rhs`` into a block of a Fortran-ordered array (the global basis's
    columns) and leaves the rest of it alone; a Woodbury solver, or an ``out`` PARDISO cannot write in, is served
    by a copy; against SuperLU."""
    Ks, _, _, _ = block
    pardiso.clear()
    K = stiffness(Ks, np.array([0.1, -0.2]))
    rng = np.random.default_rng(5)
    rhs = np.asfortranarray(rng.standard_normal((K.shape[0], 3)))
    ref = lu_solve(K, rhs)
    solve = frf.spd_solver(K)
    assert solve.writes_into
    V = np.full((K.shape[0], 7), 9.0, order="F")
    got = solve(rhs, out=V[:, 2:5])
    assert np.shares_memory(got, V)
    assert close(V[:, 2:5], ref) < RTOL
    np.testing.assert_array_equal(V[:, [0, 1, 5, 6]], 9.0)
    C = np.zeros((K.shape[0], 3))  # C order: not PARDISO's layout, filled by a copy
    solve(rhs, out=C)
    assert close(C, ref) < RTOL
    K2 = K.tolil()
    K2[3, 3] += 1e3 * K2[3, 3]  # one diagonal entry: Woodbury on the held factor
    K2 = K2.tocsr()
    solve2 = frf.spd_solver(K2)
    W = np.zeros((K.shape[0], 3), order="F")
    solve2(rhs, out=W)
    assert close(W, lu_solve(K2, rhs)) < RTOL
    assert pardiso.stats["woodbury"] >= 1


def test_an_out_overlapping_the_right_hand_side_is_filled_by_a_copy(block):
    """PARDISO must not overwrite the right-hand side it reads: an ``out`` sharing memory with ``rhs`` is served by
    a copy, and the solution is still right."""
    Ks, _, _, _ = block
    pardiso.clear()
    K = stiffness(Ks, np.array([-0.1, 0.3]))
    rng = np.random.default_rng(8)
    V = np.asfortranarray(rng.standard_normal((K.shape[0], 6)))
    ref = lu_solve(K, V[:, 0:4].copy())
    solve = frf.spd_solver(K)
    solve(V[:, 0:4], out=V[:, 1:5])  # overlapping columns
    assert close(V[:, 1:5], ref) < RTOL
    X = np.asfortranarray(rng.standard_normal((K.shape[0], 2)))
    ref = lu_solve(K, X.copy())
    solve(X, out=X)  # in place
    assert close(X, ref) < RTOL
