"""The FRF and its exact parameter derivatives on one Krylov space: a Jacobian for the price of a few FRFs.

For Rayleigh damping the dynamic stiffness is a pencil in K and M (:mod:`fe_core.solvers.frf`)::

    D(w) = K - w^2 M + j w (a M + b K) = (1 + j w b) (K - lambda(w) M),

and the receptance from loads F to outputs L is ``Z = L^T D^-1 F``. A
parameter theta that changes the matrices by ``dK, dM`` and the Rayleigh
coefficients by ``da, db`` changes D by::

    dD = (1 + j w b) dK + (-w^2 + j w a) dM + j w (da M + db K),

and Z by ``dZ = -L^T D^-1 dD D^-1 F`` (``D`` is complex symmetric, so
``L^T D^-1`` is the adjoint field: the response to the outputs as loads).

:func:`krylov_frf_derivatives` builds the block Krylov space of
``(K - sigma M)^-1 M`` started from ``(K - sigma M)^-1 [F, L]`` (one real
factorisation, as :func:`fe_core.solvers.frf.krylov_frf`) and differentiates the
Galerkin-reduced model on it. Because the space holds both the forward
(load) and the adjoint (output) Krylov spaces, the reduced model matches
moments of both ``D^-1 F`` and ``D^-1 L`` about sigma, and the derivative of
the reduced transfer function matches that of the full one (a projection
that carries both the input and the output side interpolates the parameter
gradient too: Baur, Beattie, Feng & Gugercin, SIAM J. Sci. Comput. 33, 2011;
survey in Benner, Gugercin & Willcox, SIAM Review 57, 2015; with K and M
symmetric one Galerkin space serves as both sides). As
in ``krylov_frf``, no moment count is trusted: the space grows until the
responses *and* the derivatives at all requested frequencies stop changing
(``rtol``), so the result carries its own convergence check, and an
unconverged space falls back to :func:`direct_frf_derivatives`.

In the reduced eigenbasis (``phi^T K_r phi = diag(mu)``, ``phi^T M_r phi = I``)
the reduced ``D^-1`` is ``diag(1 / (mu - lambda(w))) / (1 + j w b)``, so any
number of frequencies and directions costs small dense products: the
derivative directions enter only as the reduced matrices ``V^T dK V`` and
``V^T dM V`` (kept up to date as the space grows).

Plain numpy/scipy.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .frf import STAGNATION_RTOL, BlockKrylov, _as_load_matrix, _relative_change, _shifted_solver, _symmetric

__all__ = ["Direction", "krylov_frf_derivatives", "direct_frf_derivatives", "DerivativeInfo", "projected_response"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Direction:
    """The change of the model's matrices per unit of one parameter.

    Attributes
    ----------
    stiffness : sparse, shape (n, n), or None
        ``dK / dtheta``, N/m per unit theta (symmetric).
    mass : sparse, shape (n, n), or None
        ``dM / dtheta``, kg per unit theta (symmetric).
    damping_a : float
        ``da / dtheta``, 1/s per unit theta.
    damping_b : float
        ``db / dtheta``, s per unit theta.

    Any object with these four attributes will do (``fe_core.closure.effects.Terms``
    at a unit value is one).
    """

    stiffness: sp.spmatrix | None = None
    mass: sp.spmatrix | None = None
    damping_a: float = 0.0
    damping_b: float = 0.0


@dataclass(frozen=True)
class DerivativeInfo:
    """Diagnostics of one :func:`krylov_frf_derivatives` call.

    Attributes
    ----------
    dimension : int
        Size of the projection space.
    change : float
        Largest relative change of the responses over the last enlargement.
    derivative_change : float
        Largest relative change of the derivatives over the last
        enlargement (per direction, relative to that direction's largest
        derivative; each frequency's derivatives scaled by its largest
        response, so this is an error of ``d ln Z``).
    converged : bool
        False when the direct solver was used instead.
    sigma : float, rad^2/s^2
    solves : int
        Right-hand sides solved with the factorisation (a forward FRF needs
        about the space's dimension for one load).
    """

    dimension: int
    change: float
    derivative_change: float
    converged: bool
    sigma: float
    solves: int


def _dense_columns(A) -> np.ndarray:
    return _as_load_matrix(A.toarray() if sp.issparse(A) else A)


def _parts(directions) -> tuple[list, list, np.ndarray, np.ndarray]:
    """Sparse dK and dM lists (None where absent) and the damping arrays of the directions."""
    dK, dM, da, db = [], [], [], []
    for d in directions:
        dK.append(None if getattr(d, "stiffness", None) is None else sp.csr_matrix(d.stiffness, dtype=float))
        dM.append(None if getattr(d, "mass", None) is None else sp.csr_matrix(d.mass, dtype=float))
        da.append(float(getattr(d, "damping_a", 0.0) or 0.0))
        db.append(float(getattr(d, "damping_b", 0.0) or 0.0))
    return dK, dM, np.array(da), np.array(db)


def krylov_frf_derivatives(
    K: sp.spmatrix,
    M: sp.spmatrix,
    a: float,
    b: float,
    F,
    L,
    directions: Sequence,
    omegas,
    *,
    rtol: float = 1e-8,
    frf_rtol: float = 1e-10,
    sigma: float | None = None,
    max_dimension: int = 480,
    check_every: int | None = None,
    return_info: bool = False,
    seed=None,
    keep: dict | None = None,
):
    """Receptance ``L^T D^-1 F`` and its derivatives along ``directions``, on a converged Krylov space.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
        Symmetric stiffness (N/m, positive-definite for the Cholesky paths) and mass (kg).
    a : float, 1/s
    b : float, s
        Rayleigh coefficients, ``C = a M + b K``.
    F : ndarray, shape (n,) or (n, n_loads), N
        Loads.
    L : ndarray or sparse, shape (n, n_out)
        Output vectors (a sensor reads ``L[:, s] . u``).
    directions : sequence of Direction (or objects with the same attributes), length m
    omegas : ndarray, shape (p,), rad/s
    rtol : float
        Stop when one enlargement of the space changes the derivatives by at
        most ``rtol`` of each direction's largest (frequency-scaled)
        derivative (1e-8: far below anything a Jacobian is used for) ...
    frf_rtol : float
        ... and the responses by at most ``frf_rtol`` of each frequency's
        largest response (1e-10, as :func:`fe_core.solvers.frf.krylov_frf`: the
        responses are then the FRF itself, to the FE core's 1e-9).
    sigma : float, optional, rad^2/s^2
        Shift of the factorised pencil (see :func:`fe_core.solvers.frf.krylov_frf`).
    max_dimension : int
        Upper bound on the space's size; unconverged there, the direct
        solver is used (logged as a warning).
    check_every : int, optional
        New basis vectors between convergence checks; by default the width
        of the starting block (one block step), at least 8.
    return_info : bool
    seed : ndarray, shape (n, s), optional
        Columns the space starts with (:class:`fe_core.solvers.frf.BlockKrylov`): a nearby FE run's converged
        space (:mod:`fe_core.solvers.recycle`); the first check compares with the projection on it alone.
    keep : dict, optional
        Receives ``basis`` (the converged space, n x dim) and ``seeded`` (the seed's columns in it).

    Returns
    -------
    Z : ndarray, shape (p, n_out, n_loads), complex, m/N
    dZ : ndarray, shape (p, n_out, n_loads, m), complex, m/N per unit of each parameter
    DerivativeInfo
        Only if ``return_info``.
    """
    omegas = np.asarray(omegas, dtype=float)
    K = sp.csr_matrix(K, dtype=float)
    M = sp.csr_matrix(M, dtype=float)
    n = K.shape[0]
    F = _dense_columns(F)
    L_sparse = sp.csr_matrix(L, dtype=float) if sp.issparse(L) else None
    Ld = _dense_columns(L)
    dK, dM, da, db = _parts(directions)
    m = len(dK)

    lam = (omegas**2 - 1j * omegas * a) / (1.0 + 1j * omegas * b)
    scale = 1.0 / (1.0 + 1j * omegas * b)
    # The space and its reduced matrices V^T A V for K, M and every dK_i, dM_i (fe_core.solvers.frf.BlockKrylov).
    extra = [A for A in dK if A is not None] + [A for A in dM if A is not None]
    k_index = {i: 2 + j for j, i in enumerate(i for i in range(m) if dK[i] is not None)}
    n_k = len(k_index)
    m_index = {i: 2 + n_k + j for j, i in enumerate(i for i in range(m) if dM[i] is not None)}
    builder = BlockKrylov(K, M, np.hstack([F, Ld]), sigma, float(omegas.min() * omegas.max()), max_dimension,
                          extra=extra, seed=seed, factor=_shifted_solver)
    sigma = builder.sigma
    previous = None
    change = dchange = np.inf
    last = (np.inf, np.inf)
    next_check = every = None

    def response():
        d = builder.dim
        return _reduced_response(builder.basis[:, :d], builder.reduced[:, :d, :d], F, Ld, L_sparse, k_index,
                                 m_index, da, db, m, omegas, a, b, lam, scale)

    def kept(result):
        if keep is not None:
            keep["basis"], keep["seeded"] = builder.space_basis(), builder.seeded
        return result

    if builder.seeded:  # the first block is checked against the seed alone
        previous = response()
    while builder.grow():
        if every is None:
            every = check_every or max(8, builder.width)
            next_check = builder.dim if builder.seeded else every
        if builder.dim >= next_check or builder.seeded:  # a seeded space: after every block
            next_check = builder.dim + every
            current = response()
            if previous is not None:
                last = (change, dchange)
                change = _relative_change(current[0], previous[0])
                dchange = _derivative_change(current, previous)
                settled = change <= frf_rtol and dchange <= rtol
                # Or stalled at the round-off floor of an ill-conditioned pencil (as krylov_frf).
                floor = max(change, dchange) <= STAGNATION_RTOL and max(change, dchange) >= 0.5 * max(last)
                if settled or floor:
                    info = DerivativeInfo(builder.dim, change, dchange, True, sigma, builder.solves)
                    return kept((*current, info) if return_info else current)
            previous = current

    dim, solves = builder.dim, builder.solves
    if dim >= n:  # the space is everything: the reduced model is the model
        current = response()
        info = DerivativeInfo(dim, 0.0, 0.0, True, sigma, solves)
        return kept((*current, info) if return_info else current)
    log.warning("Krylov FRF derivatives did not converge to rtol=%g within %d vectors (last changes %.2e, %.2e); "
                "falling back to the direct solver", rtol, dim, change, dchange)
    Z, dZ = direct_frf_derivatives(K, M, a, b, F, Ld, directions, omegas)
    info = DerivativeInfo(dim, change, dchange, False, sigma, solves)
    return (Z, dZ, info) if return_info else (Z, dZ)


def _reduced_response(V, R, F, Ld, L_sparse, k_index, m_index, da, db, m, omegas, a, b, lam, scale):
    """``(Z (p, n_out, n_loads), dZ (p, n_out, n_loads, m))`` of the Galerkin-reduced model."""
    VL = (L_sparse.T @ V).T if L_sparse is not None else V.T @ Ld
    Z, dZ, _ = projected_response(R, V.T @ F, VL, k_index, m_index, da, db, m, omegas, a, b, lam, scale)
    return Z, dZ


def projected_response(R, VF, VL, k_index, m_index, da, db, m, omegas, a, b, lam, scale):
    """The reduced model's responses from its matrices alone: ``R`` (2 + extras, r, r) = ``V^T A V`` for K, M
    and the directions (``k_index``, ``m_index``: direction -> its entry of R), ``VF = V^T F`` (r, n_loads),
    ``VL = V^T L`` (r, n_out). Returns ``Z (p, n_out, n_loads)``, ``dZ (p, n_out, n_loads, m)`` and the reduced
    eigenpairs ``(mu (r,), phi (r, r))`` (``phi^T Mr phi = I``). What :func:`krylov_frf_derivatives` evaluates
    on its space, and :mod:`fe_core.solvers.reduced_basis` on a global basis."""
    mu, phi = sla.eigh(_symmetric(R[0]), _symmetric(R[1]))  # phi^T Mr phi = I, phi^T Kr phi = diag(mu)
    Fh = phi.T @ VF  # (r, n_loads)
    Lh = phi.T @ VL  # (r, n_out)
    dvec = 1.0 / (mu[None, :] - lam[:, None])  # (p, r)
    X = Lh[None, :, :] * dvec[:, :, None]  # (p, r, n_out)
    Y = Fh[None, :, :] * dvec[:, :, None]  # (p, r, n_loads)
    Z = scale[:, None, None] * np.einsum("pro,rl->pol", X, Fh)
    p = omegas.size
    dZ = np.zeros((p, Lh.shape[1], Fh.shape[1], m), dtype=complex)
    w = omegas
    Xt = np.swapaxes(X, 1, 2)  # (p, n_out, r): X^T A Y by two matrix products, not one three-operand einsum
    for i in range(m):
        S = np.zeros((p, Lh.shape[1], Fh.shape[1]), dtype=complex)
        if i in k_index:
            Ah = phi.T @ _symmetric(R[k_index[i]]) @ phi
            S += (1.0 + 1j * w * b)[:, None, None] * (Xt @ (Ah @ Y))
        if i in m_index:
            Ah = phi.T @ _symmetric(R[m_index[i]]) @ phi
            S += (-(w**2) + 1j * w * a)[:, None, None] * (Xt @ (Ah @ Y))
        if da[i] or db[i]:  # da M + db K is diagonal in the eigenbasis: da + db mu
            S += (1j * w)[:, None, None] * (Xt @ ((da[i] + db[i] * mu)[None, :, None] * Y))
        dZ[..., i] = -(scale**2)[:, None, None] * S
    return Z, dZ, (mu, phi)


def _derivative_change(current, previous) -> float:
    """Largest change of the derivatives, each frequency scaled by its largest response, per direction
    relative to that direction's largest scaled derivative (0 for a direction without any effect)."""
    Z, dZ = current
    p, m = Z.shape[0], dZ.shape[-1]
    size = np.maximum(np.abs(Z).reshape(p, -1).max(axis=1), np.finfo(float).tiny)
    now = np.abs(dZ).reshape(p, -1, m).max(axis=1) / size[:, None]  # (p, m)
    diff = np.abs(dZ - previous[1]).reshape(p, -1, m).max(axis=1) / size[:, None]
    top = now.max(axis=0)  # (m,)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(top > 0, diff.max(axis=0) / top, 0.0)
    return float(rel.max(initial=0.0))


def direct_frf_derivatives(K, M, a, b, F, L, directions: Sequence, omegas):
    """The same by one complex sparse LU per frequency (the reference): ``dZ = -G^T dD h``.

    With ``h = D^-1 F`` and the adjoint fields ``G = D^-1 L`` (D complex
    symmetric), solved together as ``1 + n_out`` right-hand sides.

    Returns
    -------
    Z : ndarray, shape (p, n_out, n_loads), complex
    dZ : ndarray, shape (p, n_out, n_loads, m), complex
    """
    omegas = np.asarray(omegas, dtype=float)
    K = sp.csc_matrix(K, dtype=float)
    M = sp.csc_matrix(M, dtype=float)
    n = K.shape[0]
    F = _dense_columns(F)
    Ld = _dense_columns(L)
    dK, dM, da, db = _parts(directions)
    nl, no, m = F.shape[1], Ld.shape[1], len(dK)
    rhs = np.hstack([F, Ld]).astype(complex)
    Z = np.empty((omegas.size, no, nl), dtype=complex)
    dZ = np.empty((omegas.size, no, nl, m), dtype=complex)
    for f, w in enumerate(omegas):
        D = (K - w**2 * M + 1j * w * (a * M + b * K)).tocsc()
        sol = spla.splu(D).solve(rhs)
        h, G = sol[:, :nl], sol[:, nl:]
        Z[f] = Ld.T @ h
        for i in range(m):
            dDh = np.zeros((n, nl), dtype=complex)
            if dK[i] is not None:
                dDh += (1.0 + 1j * w * b) * (dK[i] @ h)
            if dM[i] is not None:
                dDh += (-(w**2) + 1j * w * a) * (dM[i] @ h)
            if da[i] or db[i]:
                dDh += 1j * w * (da[i] * (M @ h) + db[i] * (K @ h))
            dZ[f, :, :, i] = -(G.T @ dDh)
    return Z, dZ
