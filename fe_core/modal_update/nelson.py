"""Exact derivatives of eigenvalues and mass-normalised mode shapes with respect to the segment factors.

For ``K phi = lambda M phi`` with ``phi^T M phi = 1`` and a parameter p (``dK = dK/dp``, ``dM = dM/dp``):

- ``d lambda = phi^T (dK - lambda dM) phi``;
- Nelson's method (Nelson, AIAA J. 14, 1976) for ``d phi``: solve ``(K - lambda M) v = -(dK - lambda dM) phi +
  d lambda M phi`` with the entry ``k`` of largest ``|phi_k|`` held at 0 (the matrix is singular along
  ``phi``; removing row and column ``k`` makes it regular for a distinct eigenvalue), then
  ``d phi = v + c phi`` with ``c = -phi^T M v - phi^T dM phi / 2`` (from the derivative of the
  normalisation).

One sparse LU per mode serves every parameter. The parameters are those of
:meth:`fe_core.model.ParametricModel.factors`: ``dK/d alpha_i = K_i`` (segment i's stiffness),
``dM/d gamma_j = M_j``. Exact only for distinct eigenvalues; a repeated one has no unique derivative and
is refused.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["eigen_derivatives", "eigen_derivatives_at", "parameter_matrices"]


def parameter_matrices(model) -> list[tuple[sp.spmatrix | None, sp.spmatrix | None]]:
    """``(dK/dp, dM/dp)`` of each parameter of ``model`` (None where a matrix does not depend on p)."""
    out = []
    for i in range(model.n_segments):
        out.append((model.stiffness_segments.segment(i), None))
    for j in model.mass_parameters:
        out.append((None, model.mass_segments.segment(int(j))))
    return out


def eigen_derivatives(K, M, lam, phi, dmats, modes=None) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of eigenvalues and mass-normalised shapes.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
    lam : ndarray, shape (r,), (rad/s)^2
        Eigenvalues; must be distinct.
    phi : ndarray, shape (n, r)
        Mass-normalised eigenvectors.
    dmats : list of (dK or None, dM or None), length p
    modes : sequence of int, optional
        Which of the r modes to differentiate (default all).

    Returns
    -------
    dlam : ndarray, shape (len(modes), p)
    dphi : ndarray, shape (len(modes), n, p)
    """
    modes = range(lam.size) if modes is None else list(modes)
    n, p = K.shape[0], len(dmats)
    K, M = sp.csc_matrix(K), sp.csc_matrix(M)
    dlam = np.zeros((len(modes), p))
    dphi = np.zeros((len(modes), n, p))
    for a, r in enumerate(modes):
        lam_r, v = float(lam[r]), phi[:, r]
        others = np.delete(lam, r)
        if others.size and np.min(np.abs(others - lam_r)) < 1e-10 * lam_r:
            raise ValueError(f"mode {r + 1}: repeated eigenvalue, its shape derivative is not unique")
        rhs = np.zeros((n, p))
        dmv = np.zeros(p)
        Mv = M @ v
        for i, (dK, dM) in enumerate(dmats):
            f = np.zeros(n)
            if dK is not None:
                f -= dK @ v
            if dM is not None:
                dMv = dM @ v
                f += lam_r * dMv
                dmv[i] = v @ dMv
            dlam[a, i] = -(v @ f)  # phi^T (dK - lam dM) phi
            rhs[:, i] = f + dlam[a, i] * Mv
        k, lu = _nelson_factor(K, M, lam_r, v)
        rhs[k, :] = 0.0
        sol = lu.solve(rhs)
        c = -(Mv @ sol) - 0.5 * dmv
        dphi[a] = sol + np.outer(v, c)
    return dlam, dphi



def _nelson_factor(K, M, lam_r: float, v: np.ndarray):
    """Nelson's matrix of one mode, factorised: ``K - lambda M`` with row and column ``k`` (the shape's
    largest entry) replaced by the unit vector, which makes it regular. Returns ``(k, splu)``."""
    n = K.shape[0]
    k = int(np.argmax(np.abs(v)))
    keep = np.ones(n)
    keep[k] = 0.0
    D = sp.diags(keep)
    unit = sp.csc_matrix(([1.0], ([k], [k])), shape=(n, n))
    return k, spla.splu(sp.csc_matrix(D @ (K - lam_r * M) @ D + unit))

def eigen_derivatives_at(K, M, lam, phi, dmats, outputs, modes, factors: dict | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`eigen_derivatives`, but the shape derivatives only as read by ``outputs`` (n, n_read):
    ``dpsi = outputs^T d phi``, by the adjoint of Nelson's solve.

    Nelson's matrix ``A`` (``K - lambda M`` with row and column ``k`` replaced by the unit vector) is
    symmetric, so ``outputs^T A^-1 rhs = X^T rhs`` with ``A X = outputs``, and ``phi^T M A^-1 rhs = y^T rhs``
    with ``A y = M phi``: one solve of ``n_read + 1`` right-hand sides per mode serves any number of
    parameters (the closure's candidate effects), kept in ``factors`` across calls on the same K, M.

    Returns ``dlam`` (len(modes), p) and ``dpsi`` (len(modes), n_read, p).
    """
    K, M = sp.csc_matrix(K), sp.csc_matrix(M)
    Lt = sp.csc_matrix(outputs)
    n, p = K.shape[0], len(dmats)
    factors = {} if factors is None else factors
    dlam = np.zeros((len(modes), p))
    dpsi = np.zeros((len(modes), Lt.shape[1], p))
    for a, r in enumerate(modes):
        lam_r, v = float(lam[r]), phi[:, r]
        Mv = M @ v
        if r not in factors:
            k, lu = _nelson_factor(K, M, lam_r, v)
            sol = lu.solve(np.column_stack([Lt.toarray(), Mv]))
            sol[k, :] = 0.0  # Nelson zeroes the right-hand side's row k: X^T rhs then skips it
            factors[r] = sol
        sol = factors[r]
        F = np.zeros((n, p), order="F")
        dmv = np.zeros(p)
        for i, (dK, dM) in enumerate(dmats):
            if dK is not None:
                F[:, i] -= dK @ v
            if dM is not None:
                dMv = dM @ v
                F[:, i] += lam_r * dMv
                dmv[i] = v @ dMv
        dlam[a] = -(v @ F)
        proj = sol.T @ F + np.outer(sol.T @ Mv, dlam[a])  # (n_read + 1, p): [X y]^T (F + M phi dlam)
        c = -proj[-1] - 0.5 * dmv
        dpsi[a] = proj[:-1] + np.outer(Lt.T @ v, c)
    return dlam, dpsi
