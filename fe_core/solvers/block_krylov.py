"""The block Krylov space every projection of the FE core is built on (:class:`BlockKrylov`).

Split from :mod:`fe_core.solvers.frf`, which gives it its shifted factorisation (``factor``) and re-exports it.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["BlockKrylov", "COLUMN_MAJOR_ROWS"]

#: Spaces of models with at least this many DOFs are stored column-major (:class:`BlockKrylov`).
COLUMN_MAJOR_ROWS = 50_000


def _as_load_matrix(F) -> np.ndarray:
    F = np.asarray(F, dtype=float)
    return F[:, None] if F.ndim == 1 else F


def _symmetric(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)


class BlockKrylov:
    """The block Krylov space of ``(K - sigma M)^-1 M`` from ``(K - sigma M)^-1 start``, grown a block at a time.

    The one builder of projection spaces in the code base: :func:`krylov_space`
    (and so :func:`krylov_frf` and :class:`fe_core.solvers.adjoint.ReducedResponse`) and
    :func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives` grow their spaces
    with it and differ only in what they test for convergence between blocks.

    Each block is orthogonalised twice against the whole basis (full
    re-orthogonalisation keeps the projection exact to round-off) and reduced by
    a column-pivoted QR, whose leading columns span the block even when it is
    rank-deficient (the benchmark's load is the sum of its sensor loads). The
    reduced matrices ``V^T A V`` of K, M and the ``extra`` matrices grow with the
    space (each new block is multiplied by every matrix once), so a convergence
    check costs a small eigenproblem, not a projection of the whole space.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
        Symmetric stiffness (N/m) and mass (kg).
    start : ndarray, shape (n, k)
        The starting loads.
    sigma : float or None
        Shift of the factorised pencil (see :func:`krylov_frf`); ``centre`` is the shift used when K
        is not positive-definite and ``sigma`` is None.
    max_dimension : int
        Upper bound on the space's size.
    extra : sequence of sparse (n, n)
        Further matrices whose reduced forms are kept (``reduced[2:]``, in order).
    factor : callable
        ``factor(K, M, sigma, centre) -> (solve, sigma used)``: the shifted factorisation
        (:func:`fe_core.solvers.frf._shifted_solver`).
    seed : ndarray, shape (n, s), optional
        Columns the space starts with (orthonormalised here), before the first block: the converged space of
        a nearby FE run (:mod:`fe_core.solvers.recycle`). The Galerkin projection uses the exact matrices on
        whatever space it is given, so a seed changes how fast the responses converge, not what they
        converge to; the space may grow by ``max_dimension`` beyond it.

    Attributes
    ----------
    basis : ndarray, shape (n, cap)
        Orthonormal columns; the first ``dim`` are the space.
    reduced : ndarray, shape (2 + len(extra), cap, cap)
        ``basis^T A basis`` for K, M and the extra matrices (the leading ``dim x dim`` block).
    dim, width, solves, sigma
        The space's size, the first block's width, the right-hand sides solved and the shift used.
    """

    def __init__(self, K, M, start, sigma: float | None, centre: float, max_dimension: int, extra=(), seed=None,
                 factor=None):
        K = sp.csr_matrix(K, dtype=float)
        M = sp.csr_matrix(M, dtype=float)
        self.solve, self.sigma = factor(K, M, sigma, centre)
        n = K.shape[0]
        s = 0 if seed is None else min(seed.shape[1], n)
        self.cap = min(max_dimension + s, n)
        # Column-major for a large model: only the columns written are touched, so the memory is the space's,
        # n x dim, not n x cap (a row-major row of 480 doubles fills a page: 1.8 GB at 464k DOFs). Small models
        # keep row-major (their arithmetic, BLAS's blocking included, stays what it was).
        self.basis = np.empty((n, self.cap), order="F" if n >= COLUMN_MAJOR_ROWS else "C")
        self.mats = [K, M, *extra]
        self.reduced = np.zeros((len(self.mats), self.cap, self.cap))
        self.dim = 0
        self.width = None
        self.seeded = 0
        if s:
            self._seed(np.asarray(seed, dtype=float)[:, :s])
        start = _as_load_matrix(start)
        self.solves = start.shape[1]
        self._block = self.solve(start)
        self._next = None  # M q of the last block: the next block is its solve, done when asked for

    def space_basis(self) -> np.ndarray:
        """The space's columns, n x dim: a view of a column-major basis (no copy, and the columns never
        written stay untouched), a copy of a row-major one."""
        V = self.basis[:, : self.dim]
        return V if self.basis.flags.f_contiguous else V.copy()

    def _seed(self, seed: np.ndarray) -> None:
        """Start the space with the columns of ``seed`` (orthonormalised, dependent ones dropped)."""
        q, r, _ = sla.qr(seed, mode="economic", pivoting=True)
        d = np.abs(np.diag(r))
        rank = int(np.sum(d > 1e-10 * max(1.0, d.max(initial=0.0))))
        q = q[:, :rank]
        self.basis[:, :rank] = q
        for t, A in enumerate(self.mats):
            self.reduced[t, :rank, :rank] = q.T @ (A @ q)
        self.dim = self.seeded = rank
        self._raw: list[np.ndarray] = []  # the Krylov blocks of a seeded space (_grow_seeded)

    def grow(self) -> bool:
        """Add the next block; False (and no change) when the space cannot grow: the new block
        lies in the space, or ``max_dimension`` is reached."""
        if self._next is not None:
            self._block = self.solve(self._next)
            self.solves += self._next.shape[1]
            self._next = None
        block, dim, basis = self._block, self.dim, self.basis
        if block is None:
            return False
        if self.seeded:
            return self._grow_seeded(block)
        for _ in range(2):
            block -= basis[:, :dim] @ (basis[:, :dim].T @ block)
        q, r, _ = sla.qr(block, mode="economic", pivoting=True)
        d = np.abs(np.diag(r))
        rank = int(np.sum(d > 1e-13 * max(1.0, d.max(initial=0.0))))
        room = self.cap - dim
        if rank == 0 or room == 0:
            self._block = None
            return False
        q = q[:, : min(rank, room)]
        k = q.shape[1]
        if self.width is None:
            self.width = k
        basis[:, dim : dim + k] = q
        self._next = self._extend_reduced(dim, q)
        self.dim = dim + k
        self._block = None
        return True

    def _extend_reduced(self, dim: int, q: np.ndarray) -> np.ndarray:
        """The new rows and columns of every ``V^T A V`` for the columns ``q`` just written at ``dim``; returns
        ``M q``. A large (column-major) space takes one matrix at a time, so only two n x k products are alive,
        not one per matrix plus their n x (k x matrices) concatenation (2.2 GB at 1M DOFs with a Jacobian's 9
        segment matrices); a small one keeps the one product of the concatenation (its arithmetic as before)."""
        k = q.shape[1]
        V = self.basis[:, : dim + k]
        if not self.basis.flags.f_contiguous:
            products = [A @ q for A in self.mats]
            cols = V.T @ np.hstack(products)  # the new rows and columns of every V^T A V
            for t in range(len(self.mats)):
                col = cols[:, t * k : (t + 1) * k]
                self.reduced[t, : dim + k, dim : dim + k] = col
                self.reduced[t, dim : dim + k, :dim] = col[:dim].T
            return products[1]
        Vt = V.T
        Mq = None
        for t, A in enumerate(self.mats):
            product = A @ q
            col = Vt @ product
            self.reduced[t, : dim + k, dim : dim + k] = col
            self.reduced[t, dim : dim + k, :dim] = col[:dim].T
            if t == 1:
                Mq = product
        return Mq


    def _grow_seeded(self, block: np.ndarray) -> bool:
        """One step of a seeded space: the Krylov recurrence runs on its own blocks (orthonormal among
        themselves, not against the seed: the seed's images are never needed), and each block joins the space
        as far as it is new. So the space always holds the new operator's Krylov space besides the seed. A
        step may add nothing (the seed held the block already); False when the recurrence is exhausted or the
        space full."""
        raw = self._raw
        for _ in range(2):
            for R in raw:
                block -= R @ (R.T @ block)
        q, r, _ = sla.qr(block, mode="economic", pivoting=True)
        d = np.abs(np.diag(r))
        rank = int(np.sum(d > 1e-13 * max(1.0, d.max(initial=0.0))))
        self._block = None
        if rank == 0:
            return False
        q = q[:, :rank]
        raw.append(q)
        if self.width is None:
            self.width = rank
        self._next = self.mats[1] @ q  # the recurrence: M times the Krylov block itself
        dim, basis = self.dim, self.basis
        new = q.copy()
        for _ in range(2):
            new -= basis[:, :dim] @ (basis[:, :dim].T @ new)
        qn, rn, _ = sla.qr(new, mode="economic", pivoting=True)
        k = min(int(np.sum(np.abs(np.diag(rn)) > 1e-12)), self.cap - dim)  # unit columns: what is left is new
        if k <= 0:
            return self.cap > dim
        qn = qn[:, :k]
        basis[:, dim : dim + k] = qn
        self._extend_reduced(dim, qn)
        self.dim = dim + k
        return True
