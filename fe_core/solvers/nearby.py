"""Solves with a factor of a nearby matrix: conjugate gradients preconditioned by the last factorisation.

Consecutive FE runs of an update factor ``K(alpha) = K_0 + sum_i (1 + alpha_i) K_i`` at nearby factors: the
Gauss-Newton steps of a converging update, the intervals' steps at its optimum. With the Cholesky factor of
``K(alpha_0)`` as preconditioner the spectrum of ``K(alpha_0)^-1 K(alpha)`` lies in ``[min r_i, max r_i]``,
``r_i = (1 + alpha_i) / (1 + alpha_0,i)`` (each ``K_i`` is positive semi-definite), so conjugate gradients
converge at ``(sqrt(kappa) - 1) / (sqrt(kappa) + 1)`` per step: on the 8,388-DOF bracket, a change of every
factor by 1e-4 takes 3 steps to a preconditioned residual of 1e-12, 1e-2 takes 5, 0.1 takes 8.

Each step costs one solve with the held factor (and a product with K), so the iteration pays only while
``(solves per right-hand side - 1) x (right-hand sides of the FE run) x (one solve)`` stays below one
factorisation. :func:`pcg_budget` turns that into the most solves per right-hand side worth spending, from
PARDISO's operation counts (the factorisation's floating point operations, the factor's entries: a solve reads
every entry twice) and the right-hand sides the handle served in its previous FE run (the Krylov space of an
FRF with its Jacobian: 50-100); the rates of the two kernels on this machine are :data:`FACTOR_RATE` and
:data:`SOLVE_RATE`. A deterministic rule, so a run repeats its own arithmetic. :class:`NearbySolver` runs
block CG within that budget; the first call that does not converge within it refactors in place (PARDISO
phase 22 on the same analysis) and solves directly from then on.

The stopping rule: every column's preconditioned residual ``||K_0^-1 r|| <= PCG_RTOL ||x||``. The
preconditioned residual is the error up to ``kappa`` (close to 1 here), and ``PCG_RTOL = 1e-12`` is two orders
below the Krylov FRF's own tolerance (responses to 1e-10 of each frequency's largest,
:func:`fe_core.solvers.frf.krylov_frf`): the space it builds is the direct solver's to far below what the FRF
resolves. Measured: the solutions agree with a fresh factorisation's to 1e-11 (the factorisation's own
round-off, ``cond(K) eps``).
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp

__all__ = ["NearbySolver", "pcg_budget", "block_pcg", "PCG_RTOL", "FACTOR_RATE", "SOLVE_RATE", "MAX_PCG_SOLVES"]

log = logging.getLogger(__name__)

#: Stop when every column's preconditioned residual is below this fraction of its solution (module docstring).
PCG_RTOL = 1e-12
#: Floating point operations a second of PARDISO's numerical factorisation and of its solve phase (per
#: right-hand side, memory-bound) on the 2-core machine of docs/results/scaling.md (one thread, the 118k-464k-DOF
#: brackets); only their ratio enters the rule.
FACTOR_RATE = 8e9
SOLVE_RATE = 1e9
#: Never more solves per right-hand side than this, whatever the rule allows (convergence that slow means
#: the factor is far from the matrix).
MAX_PCG_SOLVES = 12
#: Right-hand sides an FE run is expected to need before a handle has served one (a Jacobian's Krylov space).
DEFAULT_RHS = 60


def pcg_budget(factor_mflop: float, nnz_factor: int, expected_rhs: int) -> int:
    """The most solves per right-hand side for which CG on a held factor costs less than a new factorisation.

    ``(k - 1) rhs solve <= factorisation`` with ``solve = 4 nnz(L) / SOLVE_RATE`` (forward and backward
    substitution, two operations an entry each) and ``factorisation = flop / FACTOR_RATE``; at most
    :data:`MAX_PCG_SOLVES`. Below 2 the iteration is not worth starting.
    """
    if factor_mflop <= 0 or nnz_factor <= 0:
        return 0
    rhs = max(int(expected_rhs), 1) if expected_rhs else DEFAULT_RHS
    factor = factor_mflop * 1e6 / FACTOR_RATE
    solve = 4.0 * nnz_factor / SOLVE_RATE
    return int(min(MAX_PCG_SOLVES, 1 + np.floor(factor / (rhs * solve))))


def block_pcg(A, precondition, B: np.ndarray, rtol: float = PCG_RTOL, max_solves: int = MAX_PCG_SOLVES):
    """Conjugate gradients for ``A X = B``, every column at once, preconditioned by ``precondition``.

    Parameters
    ----------
    A : sparse, shape (n, n)
        Symmetric positive-definite.
    precondition : callable
        ``R (n, k) -> M^-1 R``, M symmetric positive-definite (a factor of a nearby matrix).
    B : ndarray, shape (n, k)
    rtol : float
        Every column stops when its preconditioned residual is below ``rtol`` times its solution.
    max_solves : int
        Calls of ``precondition`` allowed (one per step, the first included).

    Returns
    -------
    X : ndarray, shape (n, k)
    solves : int
        Calls of ``precondition`` made.
    converged : bool
    """
    X = np.zeros_like(B)
    R = B.copy()
    Z = precondition(R)
    solves = 1
    P = Z.copy()
    rz = np.einsum("ij,ij->j", R, Z)
    while True:
        Q = A @ P
        pq = np.einsum("ij,ij->j", P, Q)
        step = np.divide(rz, pq, out=np.zeros_like(rz), where=pq > 0)
        X += step * P
        R -= step * Q
        if solves >= max_solves:
            return X, solves, False
        Z = precondition(R)
        solves += 1
        size = np.linalg.norm(X, axis=0)
        if np.all(np.linalg.norm(Z, axis=0) <= rtol * np.where(size > 0, size, 1.0)):
            return X, solves, True
        rz_new = np.einsum("ij,ij->j", R, Z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
        P = Z + beta * P
        rz = rz_new


class NearbySolver:
    """``rhs -> A^-1 rhs`` by block CG on the factor a pooled handle holds (``fe_core.solvers.pardiso``).

    Parameters
    ----------
    handle
        The pooled PARDISO handle (its ``solve`` applies the held factor; ``factor(data, digest)`` refactors).
    A : scipy.sparse.csr_matrix, shape (n, n)
        The matrix to solve (full, symmetric).
    upper_data : ndarray
        A's upper triangle on the handle's pattern (what a refactorisation factors).
    digest : str
        Its digest (the pool's key for the new factor).
    budget : int
        Solves per right-hand side allowed (:func:`pcg_budget`).
    stats : dict
        The pool's counters (``pcg_solves``, ``nearby_refactored``).
    """

    def __init__(self, handle, A: sp.csr_matrix, upper_data: np.ndarray, digest: str, budget: int, stats: dict):
        self.handle, self.A, self.upper_data, self.digest = handle, A, upper_data, digest
        self.budget, self.stats = int(budget), stats
        self.direct = False
        self.base = handle.data  # the factor this solver iterates on

    def __call__(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        B = rhs.reshape(rhs.shape[0], -1)
        if not self.direct:
            if self.handle.data is not self.base:
                raise RuntimeError("the pooled factor under a CG solver changed")
            X, solves, ok = block_pcg(self.A, self.handle.solve, B, max_solves=self.budget)
            self.stats["pcg_solves"] += solves * B.shape[1]
            if ok:
                return X.reshape(rhs.shape)
            log.debug("CG on the held factor needed more than %d solves; refactoring", self.budget)
            self._refactor()
        return self.handle.solve(B).reshape(rhs.shape)

    def _refactor(self) -> None:
        """A numerical factorisation of A on the handle's analysis (this solver is its only reader)."""
        if self.handle.pins != 1 or not self.handle.factor(self.upper_data, self.digest):
            raise RuntimeError("cannot refactor a shared or failing PARDISO handle for a CG solver")
        self.stats["nearby_refactored"] += 1
        self.direct = True
        self.A = None
