"""Frequency response of ``M z'' + C z' + K z = F exp(j w t)`` at selected DOFs.

Two solvers with one signature:

:func:`direct_frf`
    One complex sparse LU of ``-w^2 M + j w C + K`` per frequency. Exact to
    round-off and general in ``C``; the reference in tests.
:func:`krylov_frf`
    For Rayleigh damping ``C = a M + b K`` the dynamic stiffness is a pencil
    in K and M alone,

        -w^2 M + j w C + K = (1 + j w b) (K - lambda(w) M),
        lambda(w) = (w^2 - j w a) / (1 + j w b),

    so every frequency is a shifted solve of the same pencil. One real
    factorisation of ``K - sigma M`` generates the block Krylov space of ``(K - sigma M)^-1 M``
    started from ``(K - sigma M)^-1 F``; the Galerkin projection of (K, M) on
    it matches moments of the transfer function about ``sigma`` (twice as
    many as the space's dimension, since K and M are symmetric and the
    outputs are the load DOFs or a subset). The space grows until the
    responses at all requested frequencies stop changing to ``rtol``
    entry-wise, so the result carries its own convergence check. The reduced
    pencil is diagonalised once, after which any number of frequencies costs
    a few small matrix products. The space is grown by :class:`BlockKrylov`,
    the one builder that :mod:`fe_core.solvers.frf_derivatives` and
    :mod:`fe_core.solvers.adjoint` use as well.

    The factorisation at ``sigma = 0`` (K positive-definite) is a LAPACK banded
    Cholesky when the bandwidth is small (the structured meshes here number
    nodes x-slowest, giving a band of about 100 for 3510 DOFs), else a
    fill-reducing sparse Cholesky by MKL PARDISO (unstructured tet meshes,
    :func:`spd_solver`; chosen by the measurements in ``docs/results/solvers.md``). A
    K that is not positive-definite (no supports), or an explicit shift, gets a
    SuperLU factorisation of the indefinite ``K - sigma M`` at the centre of
    the band.
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .block_krylov import COLUMN_MAJOR_ROWS, BlockKrylov, _as_load_matrix, _symmetric
from .upper import half_bandwidth, upper_triangle

__all__ = [
    "direct_frf",
    "krylov_frf",
    "krylov_space",
    "KrylovSpace",
    "BlockKrylov",
    "KrylovInfo",
    "hz_to_rad",
    "spd_solver",
]

log = logging.getLogger(__name__)


def hz_to_rad(freqs_hz) -> np.ndarray:
    """Angular frequencies ``2 pi f``, rad/s."""
    return 2.0 * np.pi * np.asarray(freqs_hz, dtype=float)


def direct_frf(
    K: sp.spmatrix,
    M: sp.spmatrix,
    C: sp.spmatrix,
    F: np.ndarray,
    omegas: np.ndarray,
    out_dofs: np.ndarray,
) -> np.ndarray:
    """Receptance by a complex sparse LU per frequency.

    Parameters
    ----------
    K, M, C : sparse, shape (n, n)
        Stiffness (N/m), mass (kg), damping (N s/m) on the free DOFs.
    F : ndarray, shape (n,) or (n, n_loads), N
        Load amplitudes, one column per load case.
    omegas : ndarray, shape (p,), rad/s
    out_dofs : ndarray, shape (n_out,), int
        Free-DOF indices at which the response is returned.

    Returns
    -------
    ndarray, shape (p, n_out, n_loads), complex, m/N
    """
    F = _as_load_matrix(F)
    out = np.empty((len(omegas), len(out_dofs), F.shape[1]), dtype=complex)
    K, M, C = (sp.csc_matrix(A) for A in (K, M, C))
    for i, w in enumerate(np.asarray(omegas, dtype=float)):
        A = (K - w**2 * M + 1j * w * C).tocsc()
        out[i] = spla.splu(A).solve(F.astype(complex))[out_dofs]
    return out


@dataclass(frozen=True)
class KrylovInfo:
    """Diagnostics of one :func:`krylov_frf` call.

    Attributes
    ----------
    dimension : int
        Size of the projection space.
    change : float
        Largest entry-wise relative change of the responses over the last
        enlargement of the space (the convergence measure).
    converged : bool
    sigma : float, rad^2/s^2
        Real shift of the factorised pencil.
    """

    dimension: int
    change: float
    converged: bool
    sigma: float


def krylov_frf(
    K: sp.spmatrix,
    M: sp.spmatrix,
    a: float,
    b: float,
    F: np.ndarray,
    omegas: np.ndarray,
    out_dofs: np.ndarray,
    *,
    rtol: float = 1e-10,
    sigma: float | None = None,
    max_dimension: int = 240,
    check_every: int = 8,
    return_info: bool = False,
    seed=None,
    keep: dict | None = None,
):
    """Receptance for Rayleigh damping ``C = a M + b K`` by a converged Krylov projection.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
        Symmetric stiffness (N/m) and mass (kg) on the free DOFs.
    a : float, 1/s
    b : float, s
    F : ndarray, shape (n,) or (n, n_loads), N
    omegas : ndarray, shape (p,), rad/s
    out_dofs : ndarray, shape (n_out,), int
    rtol : float
        Stop when one enlargement of the space changes the responses at every
        frequency by at most ``rtol`` relative to the largest response at that
        frequency. (An entry-wise test cannot go below round-off on the
        smallest entries, about 1e-9 for the benchmark, which is also the
        accuracy of the direct solve.)
    sigma : float, optional, rad^2/s^2
        Real shift of the factorised pencil. By default 0 when K is
        positive-definite (a banded Cholesky when K is narrow-banded, else
        PARDISO's sparse Cholesky), else ``w_min * w_max`` (the geometric
        centre of the band) with SuperLU; an explicit non-zero shift also
        uses SuperLU.
    max_dimension : int
        Upper bound on the space's size; if reached unconverged, the direct
        solver is used instead (logged as a warning).
    check_every : int
        Number of new basis vectors between convergence checks.
    return_info : bool
    seed, keep
        A space to start from, and a dict that receives the converged one (``basis``, ``seeded``), as in
        :func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives`.

    Returns
    -------
    ndarray, shape (p, n_out, n_loads), complex, m/N
    KrylovInfo
        Only if ``return_info``.
    """
    space = krylov_space(K, M, a, b, F, omegas, out_dofs, rtol=rtol, sigma=sigma, max_dimension=max_dimension,
                         check_every=check_every, seed=seed, keep=keep)
    info = space.info
    if info.converged:
        return (space.responses, info) if return_info else space.responses
    log.warning(
        "Krylov FRF did not converge to rtol=%g within %d vectors (last change %.2e); "
        "falling back to the direct solver",
        rtol,
        info.dimension,
        info.change,
    )
    C = a * M + b * K
    result = direct_frf(K, M, C, _as_load_matrix(F), np.asarray(omegas, dtype=float), out_dofs)
    return (result, info) if return_info else result


@dataclass(frozen=True)
class KrylovSpace:
    """The converged projection space of :func:`krylov_space`.

    Attributes
    ----------
    basis : ndarray, shape (n, d)
        Orthonormal columns spanning the block Krylov space of the loads.
    stiffness, mass : ndarray, shape (d, d)
        ``basis^T K basis`` and ``basis^T M basis`` (symmetrised).
    responses : ndarray, shape (p, n_out, n_loads), complex, m/N
        The projected responses at ``out_dofs`` (what :func:`krylov_frf` returns).
    info : KrylovInfo
        ``converged`` is False if ``max_dimension`` was reached first (everything
        above is then the last, unconverged space).
    """

    basis: np.ndarray
    stiffness: np.ndarray
    mass: np.ndarray
    responses: np.ndarray
    info: KrylovInfo


def krylov_space(
    K: sp.spmatrix,
    M: sp.spmatrix,
    a: float,
    b: float,
    F: np.ndarray,
    omegas: np.ndarray,
    out_dofs: np.ndarray,
    *,
    rtol: float = 1e-10,
    sigma: float | None = None,
    max_dimension: int = 240,
    check_every: int = 8,
    seed=None,
    keep: dict | None = None,
) -> KrylovSpace:
    """The converged projection space of :func:`krylov_frf` (same arguments), for reuse.

    Grown by :class:`BlockKrylov` until the responses at ``out_dofs`` to every
    column of F stop changing (``rtol``, or the round-off floor
    ``STAGNATION_RTOL``), checked every ``check_every`` new vectors. ``seed``: columns the space starts
    with (:class:`BlockKrylov`); the first check then compares with the projection on the seed alone.
    """
    F = _as_load_matrix(F)
    omegas = np.asarray(omegas, dtype=float)
    n, n_loads = F.shape
    builder = BlockKrylov(K, M, F, sigma, float(omegas.min() * omegas.max()), max_dimension, seed=seed,
                          factor=_shifted_solver)
    lam = (omegas**2 - 1j * omegas * a) / (1.0 + 1j * omegas * b)
    scale = 1.0 / (1.0 + 1j * omegas * b)

    def responses_of(b_) -> np.ndarray:
        d, V = b_.dim, b_.basis[:, : b_.dim]
        return _project(b_.reduced[0, :d, :d], b_.reduced[1, :d, :d], V[out_dofs], V.T @ F, lam, scale)

    previous = None
    current = None
    change = np.inf
    next_check = check_every
    if builder.seeded:  # the first block is checked against the seed alone
        previous = current = responses_of(builder)
        next_check = builder.dim + 1

    def space(info: KrylovInfo) -> KrylovSpace:
        d = builder.dim
        Kr, Mr = builder.reduced[0, :d, :d], builder.reduced[1, :d, :d]
        if keep is not None and info.converged:
            keep["basis"], keep["seeded"] = builder.space_basis(), builder.seeded
        return KrylovSpace(builder.basis[:, :d], _symmetric(Kr), _symmetric(Mr), current, info)

    def responses() -> np.ndarray:
        return responses_of(builder)

    while builder.grow():
        if builder.dim >= next_check or builder.seeded:  # a seeded space: after every block
            next_check = builder.dim + check_every
            current = responses()
            if previous is not None:
                last_change, change = change, _relative_change(current, previous)
                # Converged, or stagnated at the round-off floor of an ill-conditioned
                # pencil (parameters near -1), where more vectors cannot help.
                if change <= rtol or (change <= STAGNATION_RTOL and change >= 0.5 * last_change):
                    return space(KrylovInfo(builder.dim, change, True, builder.sigma))
            previous = current

    if builder.dim >= n:  # the space is everything: the projection is exact
        current = responses()
        return space(KrylovInfo(builder.dim, 0.0, True, builder.sigma))
    return space(KrylovInfo(builder.dim, change, False, builder.sigma))


#: A change this small that stops decreasing is accepted as the round-off floor. PARDISO's
#: Cholesky of the tet10 bracket (33,681 DOFs) leaves a floor of 6e-10 to 4e-8 (10 random
#: alphas, 32-40 vectors); at 1e-8 about one FE run in 20 of the bracket example went to the
#: direct solver (minutes each). 1e-7 of the largest response is far below measurement noise.
STAGNATION_RTOL = 1e-7

#: Largest half-bandwidth for which the banded Cholesky is used.
MAX_BANDWIDTH = 400


def _shifted_solver(K: sp.csr_matrix, M: sp.csr_matrix, sigma: float | None, centre: float):
    """A solver for ``(K - sigma M) x = f`` and the shift it uses."""
    if sigma is None or sigma == 0.0:
        banded, solve = banded_cholesky(K)
        if banded:
            if solve is not None:
                return solve, 0.0
            log.debug("K is not positive-definite (dpbtrf); using SuperLU")
        else:
            solve = spd_solver(K)
            if solve is not None:
                return solve, 0.0
            log.debug("K is not positive-definite (PARDISO Cholesky failed); using SuperLU")
        if sigma is None:
            sigma = centre
    lu = spla.splu((K - sigma * M).tocsc(), permc_spec="MMD_AT_PLUS_A")
    return lu.solve, float(sigma)


def banded_cholesky(K: sp.spmatrix):
    """(banded, solve): whether K's half-bandwidth is at most MAX_BANDWIDTH and, if it is and K is
    positive-definite, ``rhs -> K^-1 rhs`` by LAPACK's banded Cholesky (dpbtrf/dpbtrs; ``rhs`` (n,) or
    (n, k)), else None. Only the upper triangle is read."""
    bandwidth = half_bandwidth(K)  # block by block: a large K is never copied to COO here
    if bandwidth > MAX_BANDWIDTH:
        return False, None
    coo = sp.coo_matrix(K)
    upper = coo.row <= coo.col
    ab = np.zeros((bandwidth + 1, K.shape[0]))
    ab[bandwidth + coo.row[upper] - coo.col[upper], coo.col[upper]] = coo.data[upper]
    factor, info = lapack.dpbtrf(ab, lower=0)
    if info != 0:
        return True, None

    def solve(rhs: np.ndarray) -> np.ndarray:
        x, status = lapack.dpbtrs(factor, rhs, lower=0)
        if status != 0:
            raise RuntimeError(f"LAPACK dpbtrs failed with info={status}")
        return x

    return True, solve


def spd_solver(A: sp.spmatrix):
    """A solver ``rhs -> A^-1 rhs`` by MKL PARDISO's sparse Cholesky, or None if A is not
    positive-definite.

    PARDISO orders with nested dissection (METIS) and factors supernodally: on the
    33,681-DOF tet10 bracket it factors K 2.3-5 times faster than SuperLU and 5-8
    times faster than a banded Cholesky after reverse Cuthill-McKee, holding a third
    of SuperLU's memory (``docs/results/solvers.md``).
    The factor lives in MKL's memory and is released when the returned function is
    garbage-collected.

    Parameters
    ----------
    A : sparse, shape (n, n)
        Symmetric; only the upper triangle is read.

    Returns
    -------
    callable or None
        ``solve(rhs)`` for ``rhs`` of shape (n,) or (n, k), returning the same shape.
    """
    from . import pardiso

    if pardiso.ENABLED:  # the analysis, the factor or (Woodbury) a low-rank change of it reused
        return pardiso.cholesky(A)
    from pypardiso import PyPardisoSolver
    from pypardiso.pardiso_wrapper import PyPardisoError

    upper = upper_triangle(A)
    upper.sort_indices()
    solver = PyPardisoSolver(mtype=2)  # real symmetric positive-definite
    try:
        solver.factorize(upper)
    except PyPardisoError as error:  # -4: zero or negative pivot, A is not positive-definite
        log.debug("PARDISO Cholesky failed: %s", error)
        solver.free_memory(everything=True)
        return None

    def solve(rhs: np.ndarray) -> np.ndarray:
        return solver.solve(upper, np.asarray(rhs, dtype=float))

    weakref.finalize(solve, solver.free_memory, True)
    return solve


def _project(Kr, Mr, V_out, VF, lam, scale) -> np.ndarray:
    """Responses of the reduced pencil (Kr, Mr) at all shifts, shape (p, n_out, n_loads), from the
    basis rows at the outputs ``V_out`` and the projected loads ``VF``."""
    mu, phi = sla.eigh(_symmetric(Kr), _symmetric(Mr))  # phi^T Mr phi = I
    left = V_out @ phi  # (n_out, m)
    right = phi.T @ VF  # (m, n_loads)
    weights = scale[:, None] / (mu[None, :] - lam[:, None])  # (p, m)
    return np.einsum("om,pm,ml->pol", left, weights, right)


def _relative_change(current: np.ndarray, previous: np.ndarray) -> float:
    """Largest change per frequency relative to that frequency's largest response."""
    p = current.shape[0]
    diff = np.abs(current - previous).reshape(p, -1).max(axis=1)
    size = np.abs(current).reshape(p, -1).max(axis=1)
    return float(np.max(diff / np.maximum(size, np.finfo(float).tiny)))
