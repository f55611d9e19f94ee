"""FRFs of large models by modal superposition with a deflated remainder, and the direct FRF that checks it.

With Rayleigh damping ``C = a M + b K`` (the model file's, as ``fe_core`` applies it to the updated K),

    K + i w C - w^2 M = (1 + i w b) (K - s M),      s = (w^2 - i w a) / (1 + i w b),

so the receptance is exactly ``H(w) = (K - s M)^-1 / (1 + i w b)`` and, over all mass-normalised modes,
``(K - s M)^-1 = sum_r phi_r phi_r^T / (w_r^2 - s)``. The lowest modes, up to ``cutoff`` (1.5-2 times the
band's top), are found by shift-invert Lanczos on one sparse Cholesky factor of K (ARPACK through scipy's
``eigsh``, MKL PARDISO as the solver). The rest, the remainder, is summed without its modes: with the
flexibility of the modes not kept ``G = sum_{r > m} phi_r phi_r^T / w_r^2``,

    sum_{r > m} phi_r phi_r^T / (w_r^2 - s) = G + s G M G + s^2 (G M)^2 G + ...

The first term is the static remainder (residual flexibility); the others correct it for ``w`` and for the
damping, each at the cost of one more solve, converging as ``(|s| / w_{m+1}^2)^k`` (0.33^k at the band's top
with a cutoff of 1.75 times it), and are summed until they no longer change the FRF (:data:`SERIES_RTOL`).
``G`` is never formed: each term solves ``K x = P^T y`` with the kept modes removed from the load before the
solve and from the solution after it (``P = I - Phi Phi^T M``), so ``G f`` keeps its digits where the plain
``K^-1 f - sum phi phi^T f / w_r^2`` would be the small difference of two large numbers.
"""

from __future__ import annotations

import ctypes
import logging
import time

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: Remainder terms are added until the last one is below this fraction of the FRF's largest value.
SERIES_RTOL = 1e-10
#: At most this many remainder terms.
SERIES_MAX = 60


def _find_mkl() -> None:
    """Tell pypardiso where mkl_rt is (``PYPARDISO_MKL_RT``), found once: without it every new solver searches
    ``sys.prefix`` recursively (seconds on a busy machine)."""
    import glob
    import os
    import sys
    from ctypes.util import find_library

    if "PYPARDISO_MKL_RT" in os.environ:
        return
    path = find_library("mkl_rt") or find_library("mkl_rt.1")
    if path is None:
        found = sorted(glob.glob(f"{sys.prefix}/[Ll]ib*/**/*mkl_rt*", recursive=True), key=len)
        path = found[0] if found else None
    if path is not None:
        os.environ["PYPARDISO_MKL_RT"] = path


class Cholesky:
    """``rhs -> A^-1 rhs`` by MKL PARDISO's sparse Cholesky (through pypardiso's ctypes binding).

    The index arrays are converted to PARDISO's one-based int32 once, not at every solve.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive-definite; only the upper triangle is read.
    """

    def __init__(self, A: sp.spmatrix):
        _find_mkl()
        from pypardiso import PyPardisoSolver

        upper = sp.triu(A, format="csr").astype(float)
        upper.sort_indices()
        self.n = upper.shape[0]
        self.data = upper.data
        self.ia = upper.indptr.astype(np.int32) + 1
        self.ja = upper.indices.astype(np.int32) + 1
        del upper
        self.solver = PyPardisoSolver(mtype=2)  # real symmetric positive-definite
        self.solver.set_iparm(12, 0)  # CSR input
        self.solves = 0
        self._call(12, np.zeros((self.n, 1)))  # analysis and numerical factorisation

    def _call(self, phase: int, b: np.ndarray) -> np.ndarray:
        from pypardiso.pardiso_wrapper import PyPardisoError

        s = self.solver
        b = np.asfortranarray(b, dtype=float)
        x = np.zeros_like(b)
        error = ctypes.c_int32(0)
        i32, f64 = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_double)
        s._mkl_pardiso(s.pt.ctypes.data_as(ctypes.POINTER(s._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
                       ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(s.mtype)),
                       ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(self.n)),
                       self.data.ctypes.data_as(f64), self.ia.ctypes.data_as(i32), self.ja.ctypes.data_as(i32),
                       s.perm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(b.shape[1])),
                       s.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(s.msglvl)),
                       b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(error))
        if error.value != 0:
            raise PyPardisoError(error.value)
        return np.ascontiguousarray(x)

    def __call__(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        self.solves += 1
        return self._call(33, rhs.reshape(self.n, -1)).reshape(rhs.shape)

    def free(self) -> None:
        self.solver.free_memory(everything=True)


def single_threaded():
    """A context in which BLAS and MKL run on one thread: PARDISO's solve on two threads and ARPACK's BLAS
    calls differ from run to run in the last bits, one thread does not (the factorisation on two threads
    is reproducible). Used around the Lanczos and the remainder so that the data are the same at every run."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1)


def lowest_modes(K: sp.spmatrix, M: sp.spmatrix, solve, cutoff_hz: float, k: int = 30):
    """Every mode below ``cutoff_hz`` (and the first above it), mass-normalised.

    Shift-invert Lanczos about 0 (``solve`` is ``K^-1``); ``k`` grows until the highest mode found lies
    above the cutoff, so that no mode below it is missed (the k found are the k lowest).

    Returns
    -------
    omega2 : ndarray, shape (m,), (rad/s)^2, ascending (the modes below the cutoff)
    phi : ndarray, shape (n, m), mass-normalised
    omega2_next : float
        The first mode above the cutoff, (rad/s)^2: it sets how fast the remainder series converges.
    """
    from scipy.sparse.linalg import LinearOperator, eigsh

    n = K.shape[0]
    op = LinearOperator((n, n), matvec=solve, dtype=float)
    limit = (2 * np.pi * cutoff_hz) ** 2
    v0 = np.random.default_rng(0).standard_normal(n)  # ARPACK's start vector, fixed: deterministic modes
    while True:
        t0 = time.perf_counter()
        with single_threaded():
            lam, phi = eigsh(K, k=min(k, n - 1), M=M, sigma=0.0, OPinv=op, which="LM", v0=v0)
        order = np.argsort(lam)
        lam, phi = lam[order], phi[:, order]
        log.info("Lanczos: %d modes, %.5g-%.5g Hz, %.0f s", lam.size, np.sqrt(lam[0]) / 2 / np.pi,
                 np.sqrt(lam[-1]) / 2 / np.pi, time.perf_counter() - t0)
        if lam[-1] > limit or lam.size >= n - 1:
            break
        # Mode counts grow about as w (plates) to w^1.5 (solids): aim 25 % past the cutoff.
        k = int(k * 1.25 * (limit / lam[-1]) ** 0.75) + 5
    kept = lam < limit
    phi = phi[:, kept]
    phi /= np.sqrt(np.einsum("ij,ij->j", phi, M @ phi))
    return lam[kept], phi, float(lam[~kept][0]) if (~kept).any() else np.inf


def modal_frf(K, M, solve, omega2, phi, outputs, load, freqs_hz, damping, rtol: float = SERIES_RTOL,
              max_terms: int = SERIES_MAX):
    """Receptance at the sensors by modal superposition plus the deflated remainder series.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
    solve : callable, ``rhs -> K^-1 rhs``
    omega2, phi : the kept modes (:func:`lowest_modes`)
    outputs : ndarray, shape (n, n_sensors)
    load : ndarray, shape (n,), N
    freqs_hz : ndarray, shape (p,)
    damping : (a [1/s], b [s])
    rtol, max_terms : the remainder series' stop rule and cap

    Returns
    -------
    H : ndarray, shape (p, n_sensors), complex, m/N
    info : dict
        ``terms`` (remainder terms summed); what the remainder contributes, ``|static remainder| / |H|`` and
        ``|higher remainder terms| / |H|`` over lines and sensors, median and largest (``static_median``,
        ``static_max``, ``dynamic_median``, ``dynamic_max``; the largest are near antiresonances).
    """
    a, b = damping
    w = 2 * np.pi * np.asarray(freqs_hz, float)
    s = (w**2 - 1j * w * a) / (1 + 1j * w * b)  # (p,)
    with single_threaded():
        H, terms, r = _modal_and_series(K, M, solve, omega2, phi, outputs, load, s, rtol, max_terms)
        powers = r[:, None] ** np.arange(len(terms))[None]  # (p, terms)
        R = powers @ np.asarray(terms)  # (p, n_sensors)
    H = (H + R) / (1 + 1j * w * b)[:, None]
    static = terms[0][None] / (1 + 1j * w * b)[:, None]
    dynamic = R / (1 + 1j * w * b)[:, None] - static
    info = {"terms": len(terms),
            "static_median": float(np.median(np.abs(static) / np.abs(H))),
            "static_max": float(np.max(np.abs(static) / np.abs(H))),
            "dynamic_median": float(np.median(np.abs(dynamic) / np.abs(H))),
            "dynamic_max": float(np.max(np.abs(dynamic) / np.abs(H)))}
    return H, info


def _modal_and_series(K, M, solve, omega2, phi, outputs, load, s, rtol, max_terms):
    """The kept modes' sum at each ``s`` and the remainder series' terms (see :func:`modal_frf`)."""
    Mphi = M @ phi
    modal = (outputs.T @ phi) * (phi.T @ load)  # (n_sensors, m)
    H = (modal[None] / (omega2[None, None] - s[:, None, None])).sum(axis=2)  # (p, n_sensors)

    def deflated(y):  # G y = P^T K^-1 P y: the kept modes out of the load and out of the solution
        x = solve(y - Mphi @ (phi.T @ y))
        return x - phi @ (Mphi.T @ x)

    # The series in r = s / c with c = max |s| (|r| <= 1; no overflow): term k is r^k c^k G (M G)^k f.
    c = np.abs(s).max()
    r = s / c
    g = deflated(load)
    terms = [outputs.T @ g]
    scale = np.abs(H + terms[0][None]).max()
    while len(terms) < max_terms:
        g = c * deflated(M @ g)
        terms.append(outputs.T @ g)
        if np.abs(terms[-1]).max() < rtol * scale:
            break
    else:
        log.warning("remainder series: %d terms without reaching %.1e", max_terms, rtol)
    return H, terms, r


def direct_frf(K, M, outputs, load, freqs_hz, damping):
    """Receptance at the sensors by a direct sparse solve per frequency (small models: the check).

    ``(K + i w C - w^2 M) x = f`` with ``C = a M + b K`` is solved in real form, ``[[A_r, -A_i], [A_i, A_r]]
    [x_r; x_i] = [f; 0]``, by MKL PARDISO's LU (pypardiso; a complex SuperLU is several times slower here).

    Returns
    -------
    ndarray, shape (p, n_sensors), complex, m/N
    """
    import pypardiso

    a, b = damping
    K, M = sp.csr_matrix(K), sp.csr_matrix(M)
    n = K.shape[0]
    rhs = np.concatenate([load, np.zeros(n)])
    out = []
    for f in np.asarray(freqs_hz, float):
        w = 2 * np.pi * f
        A_r, A_i = K - w**2 * M, w * (a * M + b * K)
        x = pypardiso.spsolve(sp.bmat([[A_r, -A_i], [A_i, A_r]], format="csr"), rhs)
        out.append(outputs.T @ (x[:n] + 1j * x[n:]))
    return np.array(out)
