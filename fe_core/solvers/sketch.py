"""The check of a reduced evaluation: a sparse sign sketch of its full-order residual (Balabanov & Nouy, Adv.
Comput. Math. 45, 2019, "Randomized linear algebra for model reduction. Part I"; the method is described in
:mod:`fe_core.solvers.reduced_basis`, which uses it). Plain numpy/scipy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["SKETCH_ROWS", "SKETCH_NONZEROS", "sparse_sign_sketch", "Estimate", "sketched_estimate"]

#: Rows of the sketch (each costs one solve with the factor when the basis is built: 40, against the 143 of a
#: 150k model's Jacobian space) and random signs per column of it; a norm is kept to ~sqrt(2 / 40) = 22 %.
SKETCH_ROWS = 40
SKETCH_NONZEROS = 8


def sparse_sign_sketch(n: int, rows: int = SKETCH_ROWS, nonzeros: int = SKETCH_NONZEROS,
                       seed: int = 41) -> sp.csr_matrix:
    """A sparse sign embedding ``S`` (rows x n): each column has ``nonzeros`` entries ``+-1/sqrt(nonzeros)`` in
    distinct random rows, so ``E ||S x||^2 = ||x||^2`` for every x, and applying S costs ``nonzeros`` per entry."""
    rng = np.random.default_rng(seed)
    s = min(nonzeros, rows)
    row = np.argsort(rng.random((n, rows)), axis=1)[:, :s] if rows <= 64 else _distinct_rows(rng, n, rows, s)
    sign = rng.choice([-1.0, 1.0], size=(n, s)) / np.sqrt(s)
    col = np.repeat(np.arange(n), s)
    return sp.csr_matrix((sign.ravel(), (row.ravel(), col)), shape=(rows, n))


def _distinct_rows(rng, n: int, rows: int, s: int) -> np.ndarray:
    """``s`` distinct row indices per column, without an n x rows table (redrawn where two collide)."""
    out = rng.integers(0, rows, size=(n, s))
    while True:
        srt = np.sort(out, axis=1)
        bad = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
        if not bad.any():
            return out
        out[bad] = rng.integers(0, rows, size=(int(bad.sum()), s))


@dataclass(frozen=True)
class Estimate:
    """The check of one reduced evaluation.

    field_error : ndarray, shape (p,)
        The largest estimated relative error of the primal and dual fields at each line.
    relative : ndarray, shape (p, n_loads + n_out)
        The estimate of every field (the loads', then the outputs') at every line.
    residual : ndarray, shape (p, n_loads + n_out)
        The sketched norms ``||S K0^-1 r||`` of their full-order residuals.
    ok : bool
        ``field_error <= tol`` at every line (the basis's ``FIELD_TOL``).
    """

    field_error: np.ndarray
    relative: np.ndarray
    residual: np.ndarray
    ok: bool


def sketched_estimate(SAV, Vrhs, S_rhs, n_stiff: int, w_stiff, w_mass, mu, phi, lam, scale, tol: float) -> Estimate:
    """The estimate of every primal and dual field's relative error at every line (:class:`Estimate`).

    ``SAV`` (parts, k, r): the sketch of every part times V (the stiffness parts first, ``n_stiff`` of them);
    ``Vrhs`` (r, c): V^T [B, L]; ``S_rhs`` (k, c): the sketch of [B, L]; ``w_stiff``, ``w_mass``: the parts'
    weights; ``mu``, ``phi``: the reduced pencil's eigenvalues and M-orthonormal modes; ``lam``, ``scale`` at
    every line; ``tol``: the largest estimate a served point may have.
    """
    SK = np.tensordot(np.asarray(w_stiff, float), SAV[:n_stiff], axes=1) @ phi  # (k, r)
    SM = np.tensordot(np.asarray(w_mass, float), SAV[n_stiff:], axes=1) @ phi
    Bh = phi.T @ Vrhs  # (r, c)
    dvec = 1.0 / (mu[None, :] - lam[:, None])  # (p, r)
    X = dvec[:, :, None] * Bh[None, :, :]  # (p, r, c): phi^-1 y / scale
    # S r = (S K V phi - lambda S M V phi) X - S b: one (k, r) x (r, c) product per line.
    Sr = SK @ X - lam[:, None, None] * (SM @ X) - S_rhs[None, :, :]
    res = np.linalg.norm(Sr, axis=1)  # (p, c): ||K0^-1 r|| of every column at every line
    field = np.abs(scale)[:, None] * np.linalg.norm(phi @ X, axis=1)  # ||V y|| = ||y||
    # K0^-1 r is the error e = D^-1 r up to mu / (mu - lambda) in each mode: at most ~1 off resonance, the
    # quality factor at one; the reduced pencil's eigenvalues stand in for the model's (the modes of the band
    # are in the space).
    kappa = np.maximum(1.0, np.max(np.abs(mu[None, :] * dvec), axis=1))  # (p,)
    rel = kappa[:, None] * res / np.maximum(field, np.finfo(float).tiny)
    field_error = rel.max(axis=1)
    return Estimate(field_error, rel, res, bool(np.all(field_error <= tol)))
