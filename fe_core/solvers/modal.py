"""Natural frequencies and mode shapes by shift-invert Lanczos, and mode labels."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["eigenmodes", "classify_mode"]


def eigenmodes(
    K: sp.spmatrix, M: sp.spmatrix, n_modes: int, shift_hz: float = 0.0, tol: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Lowest natural frequencies above ``shift_hz`` and mass-normalised modes.

    Shift-invert Lanczos (ARPACK via ``scipy.sparse.linalg.eigsh``) on
    ``K phi = w^2 M phi``.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
        Symmetric stiffness (N/m) and positive-definite mass (kg).
    n_modes : int
    shift_hz : float, Hz
        Spectral shift; 0 finds the lowest modes of a constrained structure.
    tol : float
        ARPACK's relative accuracy of the eigenvalues (0: machine precision). A check that needs the
        frequencies only roughly (the preflight's band check of a large model) saves a third of the solves
        with 1e-3.

    Returns
    -------
    freqs : ndarray, shape (n_modes,), Hz
        Ascending.
    modes : ndarray, shape (n, n_modes)
        ``modes.T @ M @ modes = I``.
    """
    if not 1 <= n_modes < K.shape[0]:
        raise ValueError(f"n_modes must be in [1, {K.shape[0] - 1}], got {n_modes}")
    sigma = (2.0 * np.pi * shift_hz) ** 2
    K, M = sp.csc_matrix(K), sp.csc_matrix(M)
    # A fixed start vector makes ARPACK deterministic.
    v0 = np.ones(K.shape[0])
    vals, vecs = spla.eigsh(K, k=n_modes, M=M, sigma=sigma, which="LM", v0=v0, OPinv=_cholesky_inverse(K, sigma),
                             tol=tol)
    order = np.argsort(vals)
    vals, vecs = vals[order], vecs[:, order]
    freqs = np.sqrt(np.clip(vals, 0.0, None)) / (2.0 * np.pi)
    return freqs, vecs


def classify_mode(
    shape: np.ndarray, mirror: np.ndarray, in_plane_ratio: float = 0.1
) -> str:
    """Label a mode from the symmetry of its u_z field about y = 0.

    Parameters
    ----------
    shape : ndarray, shape (n_nodes, 3)
        Nodal displacements (u_x, u_y, u_z).
    mirror : ndarray, shape (n_nodes,), int
        For each node, the index of its mirror image in y -> -y.
    in_plane_ratio : float
        A mode whose u_z carries less than this share of the displacement
        norm is "in-plane".

    Returns
    -------
    {"z-bending", "torsion", "in-plane"}
        Symmetric u_z is z-bending; antisymmetric u_z is torsion.
    """
    uz = shape[:, 2]
    if np.linalg.norm(uz) < in_plane_ratio * np.linalg.norm(shape):
        return "in-plane"
    symmetric = np.linalg.norm(uz + uz[mirror])
    antisymmetric = np.linalg.norm(uz - uz[mirror])
    return "z-bending" if symmetric >= antisymmetric else "torsion"


def _cholesky_inverse(K: sp.csc_matrix, sigma: float):
    """``K^-1`` by a sparse Cholesky, else None (ARPACK's own SuperLU of ``K - sigma M``).

    The same rule as the FRF's solver (:func:`fe_core.solvers.frf._shifted_solver`): a banded K (the
    benchmark) by LAPACK's banded Cholesky, twice as fast as SuperLU in the benchmark's eigenmodes (0.074
    against 0.143 s for 10 modes; 40 solves either way); a wide band (any gmsh mesh) by PARDISO, about
    twice as fast as SuperLU for the six modes of the 33,681-DOF bracket (measured at e570f0c: git show
    0cbca1f:docs/mesh-pictures.md).
    """
    from .frf import banded_cholesky, spd_solver

    if sigma != 0.0:
        return None
    banded, solve = banded_cholesky(K)
    if not banded:
        solve = spd_solver(K)
    return None if solve is None else spla.LinearOperator(K.shape, matvec=solve, dtype=float)
