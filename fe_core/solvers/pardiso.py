"""MKL PARDISO's sparse Cholesky with the work one factorisation can serve kept (issue 28).

The closure and the fits factor ``K(alpha)`` (plus any stiffness of the effects) once per FE evaluation,
thousands of times on one sparsity pattern. :func:`cholesky` keeps, per process, a small pool of
PARDISO handles per pattern, so that

* the MKL library is located once (pypardiso searches ``sys.prefix`` with a recursive glob on every
  solver it creates: 2.5 s a solver on the 33,681-DOF bracket at load 10);
* the symbolic analysis (METIS ordering and symbolic factorisation, PARDISO phase 11) is done once per
  pattern; a new matrix of the same pattern only gets the numerical factorisation (phase 22);
* a matrix whose values equal a pooled factor's (the screen at the point the fit ended, a relocation
  at the fitted point, a point mass that leaves K as it is) reuses that factor outright;
* a matrix that differs from a pooled factor's in a few rows and columns (a grounded spring: one
  diagonal entry) is solved on that factor by the Sherman-Morrison-Woodbury formula,
  ``(K0 + E D E^T)^-1 f = y - Y (I + D Y_R)^-1 D y_R`` with ``y = K0^-1 f``, ``Y = K0^-1 E``, ``_R`` the
  changed rows: no factorisation at all.

Every path solves the same system to round-off (``tests/fe_core/test_pardiso_reuse.py`` against
SuperLU). ``ENABLED = False`` (or ``MRGP_PARDISO_REUSE=0``) restores the plain path of
:func:`fe_core.solvers.frf.spd_solver`: a new solver and both phases per matrix.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import logging
import os
import site
import sys
import threading
import weakref
from ctypes.util import find_library

import numpy as np
import scipy.sparse as sp

from .upper import upper_triangle

__all__ = ["cholesky", "ENABLED", "MAX_LOW_RANK", "stats", "clear"]

log = logging.getLogger(__name__)

#: Whether :func:`fe_core.solvers.frf.spd_solver` uses this module (off: the plain path).
ENABLED = os.environ.get("MRGP_PARDISO_REUSE", "1") != "0"
#: Most changed rows solved by Woodbury on a pooled factor (more: a numerical factorisation).
MAX_LOW_RANK = 12
#: Pooled (idle) handles kept per pattern; each holds its factor (about 75 MB on the bracket).
POOL_SIZE = 2

_POOL: dict[tuple, list["_Handle"]] = {}
#: Guards the pools (a finaliser may run in any thread); each thread has its own handles.
_LOCK = threading.RLock()
#: Counts since start (or :func:`clear`): analyses, factorisations, reuses, Woodbury solvers.
stats = {"analyses": 0, "factorisations": 0, "reused": 0, "woodbury": 0, "nearby": 0, "nearby_refactored": 0,
         "pcg_solves": 0}
#: Whether a matrix of a held factor's pattern may be solved by conjugate gradients preconditioned with that
#: factor (:mod:`fe_core.solvers.nearby`); off: a numerical factorisation (``MRGP_PARDISO_NEARBY=0``).
NEARBY = os.environ.get("MRGP_PARDISO_NEARBY", "1") != "0"
#: Factors with fewer entries are refactored: small models keep the plain path exactly (their
#: factorisation is cheap, and their results stay bit for bit what they were).
NEARBY_MIN_NNZ = 20_000_000
#: CG is tried only when it may spend this many solves per right-hand side: fewer never reach the tolerance
#: (a change of the factors by 1e-6 takes 3, fe_core.solvers.nearby).
MIN_PCG_SOLVES = 3
#: An idle handle's factor larger than this is freed when :func:`release_idle` is called (its analysis kept).
RELEASE_BYTES = 256 * 2**20


def _mkl_path() -> str | None:
    """mkl_rt as pypardiso would find it, searched once and handed to pypardiso through its variable."""
    path = os.environ.get("PYPARDISO_MKL_RT") or find_library("mkl_rt") or find_library("mkl_rt.1")
    if path is None:
        found = (glob.glob(f"{sys.prefix}/[Ll]ib*/**/*mkl_rt*", recursive=True)
                 or glob.glob(f"{site.USER_BASE}/[Ll]ib*/**/*mkl_rt*", recursive=True))
        path = sorted(found, key=len)[0] if found else None
    if path is not None:
        os.environ["PYPARDISO_MKL_RT"] = path
    return path


def _digest(*arrays) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(np.ascontiguousarray(a).view(np.uint8))
    return h.hexdigest()


class _Handle:
    """One PARDISO instance: analysed for a pattern, holding the factor of ``data`` (or none)."""

    def __init__(self, upper: sp.csr_matrix, key: tuple, pattern_digest: str, threads: int = 1):
        from pypardiso import PyPardisoSolver

        if "PYPARDISO_MKL_RT" not in os.environ:
            _mkl_path()
        self.solver = PyPardisoSolver(mtype=2)  # real symmetric positive-definite
        self.solver.set_iparm(12, 0)  # CSR input (pypardiso's _check_A sets it on every call)
        self.key = key
        self.pattern_digest = pattern_digest
        self.pattern = upper  # the matrix whose index arrays the factor was analysed for
        self.data = None  # values of the matrix factored (None: no factor)
        self.digest = None
        self.analysed = False
        self.pins = 0  # live solvers reading this pooled factor
        self.nnz_factor = 0  # entries of the Cholesky factor L (PARDISO's iparm(18))
        self.factor_mflop = 0.0  # its factorisation's work, 1e6 floating point operations (iparm(19))
        self.rhs_served = 0  # right-hand sides solved with the current pins (the last lifetime's workload)
        self.last_lifetime_rhs = 0
        self.solver.set_iparm(19, -1)  # report the factorisation's operations (phase 1)
        # Every phase runs on the threads the analysis ran on: PARDISO crashes in a numerical factorisation
        # on fewer threads than its analysis had (MKL 2026.2, measured); the pool keys handles by it.
        self.threads = int(threads)
        self._ia = (upper.indptr + 1).astype(np.int32)  # 1-based, converted once (pypardiso does it per call)
        self._ja = (upper.indices + 1).astype(np.int32)

    def call(self, phase: int, data: np.ndarray, rhs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """PARDISO's ``phase`` on ``rhs``; the solution is written in ``out`` (a Fortran-ordered float array of
        rhs's shape, returned as it is) when given, else in a new array returned in C order."""
        import ctypes

        from pypardiso.pardiso_wrapper import PyPardisoError

        s = self.solver
        b = np.asfortranarray(rhs, dtype=float)
        x = np.zeros_like(b) if out is None else out
        error = ctypes.c_int32(0)
        i32, f64 = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_double)
        data = np.ascontiguousarray(data, dtype=float)
        lib = _mkl()
        previous = lib.MKL_Set_Num_Threads_Local(self.threads) if lib is not None else None
        try:
            self._pardiso(s, phase, data, b, x, error, i32, f64)
        finally:
            if previous is not None:
                lib.MKL_Set_Num_Threads_Local(previous)
        if error.value != 0:
            raise PyPardisoError(error.value)
        return x if out is not None else np.ascontiguousarray(x)

    def _pardiso(self, s, phase, data, b, x, error, i32, f64):
        import ctypes

        s._mkl_pardiso(s.pt.ctypes.data_as(ctypes.POINTER(s._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
                       ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(s.mtype)),
                       ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(self.pattern.shape[0])),
                       data.ctypes.data_as(f64), self._ia.ctypes.data_as(i32), self._ja.ctypes.data_as(i32),
                       s.perm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(1 if b.ndim == 1 else b.shape[1])),
                       s.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(s.msglvl)),
                       b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(error))

    @property
    def factor_bytes(self) -> int:
        """Memory of the factor L held (0 without one)."""
        return 8 * self.nnz_factor if self.data is not None else 0

    def factor(self, data: np.ndarray, digest: str) -> bool:
        from pypardiso.pardiso_wrapper import PyPardisoError

        n = self.pattern.shape[0]
        try:
            if not self.analysed:
                self.call(11, data, np.zeros((n, 1)))
                self.analysed = True
                stats["analyses"] += 1
                self.nnz_factor = int(self.solver.get_iparm(18))
                self.factor_mflop = float(max(self.solver.get_iparm(19), 0))
            self.call(22, data, np.zeros((n, 1)))
        except PyPardisoError as error:  # -4: zero or negative pivot: not positive-definite
            log.debug("PARDISO Cholesky failed: %s", error)
            self.data = self.digest = None
            return False
        stats["factorisations"] += 1
        self.data, self.digest = data.copy(), digest
        return True

    def matrix(self) -> sp.csr_matrix:
        """The upper triangle factored (shares the index arrays)."""
        return sp.csr_matrix((self.data, self.pattern.indices, self.pattern.indptr), shape=self.pattern.shape)

    def solve(self, rhs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        b = rhs.reshape(rhs.shape[0], -1)
        self.rhs_served += b.shape[1]
        if out is not None and _writable_into(out, b):
            return self.call(33, self.data, b, out=out)
        x = self.call(33, self.data, b).reshape(rhs.shape)
        if out is None:
            return x
        out[...] = x
        return out

    def release_factor(self):
        """Free the factor, keep the analysis (PARDISO phase 0): a new matrix of the pattern needs only its
        numerical factorisation."""
        if self.data is not None:
            n = self.pattern.shape[0]
            self.call(0, self.data, np.zeros((n, 1)))
            self.data = self.digest = None

    def free(self):
        self.solver.free_memory(everything=True)


_MKL = None


def _mkl():
    """The MKL runtime pypardiso calls (loaded once), or None."""
    global _MKL
    if _MKL is None:
        import ctypes

        path = os.environ.get("PYPARDISO_MKL_RT") or _mkl_path()
        try:
            _MKL = ctypes.CDLL(path) if path else False
        except OSError:
            _MKL = False
    return _MKL or None


@contextlib.contextmanager
def threads(n: int | None):
    """Run this thread's PARDISO (MKL) calls inside the block on ``n`` threads (None or < 2: unchanged).

    ``MKL_Set_Num_Threads_Local`` (the C name; the lower-case symbol is the Fortran one): the setting is this thread's, restored on exit; other threads and the
    process's BLAS are not touched (the flows start every process with one MKL thread).
    """
    lib = _mkl() if n is not None and n >= 2 else None
    if lib is None:
        yield
        return
    previous = lib.MKL_Set_Num_Threads_Local(int(n))
    try:
        yield
    finally:
        lib.MKL_Set_Num_Threads_Local(int(previous))


def mkl_threads() -> int:
    """MKL's threads for this thread's calls now (1 without MKL)."""
    lib = _mkl()
    return int(lib.MKL_Get_Max_Threads()) if lib is not None else 1


def release_idle(min_bytes: int | None = None) -> int:
    """Free the factors of idle handles larger than ``min_bytes`` (default :data:`RELEASE_BYTES`), keeping their
    analyses; returns the bytes freed. An FE worker calls it after each FE run of a large model, so a process
    waiting for work holds no factor."""
    limit = RELEASE_BYTES if min_bytes is None else min_bytes
    freed = 0
    with _LOCK:
        for pool in _POOL.values():
            for h in pool:
                if not h.pins and h.data is not None and h.factor_bytes > limit:
                    freed += h.factor_bytes
                    h.release_factor()
    return freed


def _release_other_pools(key: tuple) -> None:
    for other, pool in _POOL.items():
        if other != key:
            for h in pool:
                if not h.pins and h.data is not None and h.factor_bytes > RELEASE_BYTES:
                    h.release_factor()


def _trim(pool: list):
    """Free the oldest idle handles beyond ``POOL_SIZE`` idle ones."""
    idle = [h for h in pool if not h.pins]
    for h in idle[:max(0, len(idle) - POOL_SIZE)]:
        pool.remove(h)
        h.free()


def clear():
    """Free every idle pooled factor and reset the counts."""
    with _LOCK:
        _clear()


def _clear():
    for pool in _POOL.values():
        for h in [h for h in pool if not h.pins]:
            pool.remove(h)
            h.free()
    _POOL.clear()
    for k in stats:
        stats[k] = 0


def _changed_rows(upper: sp.csr_matrix, base: np.ndarray, data: np.ndarray):
    """Rows (and columns) where ``data`` differs from ``base`` on the common upper pattern, and the
    symmetric change restricted to them, or None if more than ``MAX_LOW_RANK`` rows change."""
    where = np.flatnonzero(data != base)
    if where.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, 0))
    if where.size > MAX_LOW_RANK * (MAX_LOW_RANK + 1) // 2:  # more entries than an upper triangle of that many
        return None
    rows = np.searchsorted(upper.indptr, where, side="right") - 1
    cols = upper.indices[where]
    R = np.unique(np.concatenate([rows, cols]))
    if R.size > MAX_LOW_RANK:
        return None
    pos = {r: k for k, r in enumerate(R)}
    D = np.zeros((R.size, R.size))
    for i, j, v in zip(rows, cols, data[where] - base[where]):
        D[pos[i], pos[j]] += v
        if i != j:
            D[pos[j], pos[i]] += v
    return R, D


def _woodbury(handle: _Handle, R: np.ndarray, D: np.ndarray):
    """``rhs -> (K0 + E_R D E_R^T)^-1 rhs`` on the factor of K0 held by ``handle``."""
    n = handle.pattern.shape[0]
    E = np.zeros((n, R.size))
    E[R, np.arange(R.size)] = 1.0
    Y = handle.solve(E)  # K0^-1 E, (n, r)
    cap = np.eye(R.size) + D @ Y[R]  # I + D Y_R
    data = handle.data

    def solve(rhs: np.ndarray) -> np.ndarray:
        if handle.data is not data:
            raise RuntimeError("the pooled factor under a Woodbury solver changed")
        rhs = np.asarray(rhs, dtype=float)
        b = rhs.reshape(n, -1)
        y = handle.solve(b)
        x = y - Y @ np.linalg.solve(cap, D @ y[R])
        return x.reshape(rhs.shape)

    return solve


def cholesky(A: sp.spmatrix):
    """A solver ``rhs -> A^-1 rhs`` for a symmetric positive-definite A, or None if A is not.

    Same contract as :func:`fe_core.solvers.frf.spd_solver` (only A's upper triangle is read); the
    factor of a pooled handle of A's pattern is reused, updated by Woodbury, or refactored
    numerically (see the module's docstring). The returned function holds its handle until it is
    garbage-collected; the handle then goes back to the pool with its factor.
    """
    upper = upper_triangle(A)  # without scipy's COO copy (fe_core.solvers.upper)
    upper.sort_indices()
    key = (threading.get_ident(), upper.shape[0], mkl_threads())
    pattern = _digest(upper.indptr, upper.indices)
    digest = _digest(upper.data)
    with _LOCK:
        return _cholesky(upper, key, pattern, digest, A)


def _cholesky(upper, key, pattern, digest, A=None):
    pool = _POOL.setdefault(key, [])
    held = [h for h in pool if h.data is not None]
    # 1. The same matrix: the factor serves as it is.
    for h in held:
        if h.pattern_digest == pattern and h.digest == digest and np.array_equal(h.data, upper.data):
            stats["reused"] += 1
            return _pinned(pool, h, h.solve)
    # 2. A few changed rows and columns (a spring: one diagonal entry): Woodbury on a held factor.
    for h in held:
        if h.pattern_digest == pattern:
            change = _changed_rows(upper, h.data, upper.data)
        else:  # sparse sums drop explicit zeros: the pattern of K + spring may differ from K's
            change = _changed_rows_sparse(upper, h.matrix())
        if change is not None:
            stats["woodbury"] += 1
            return _pinned(pool, h, _woodbury(h, *change))
    # 3. Another matrix of the pattern (K at other segment factors): conjugate gradients preconditioned by a
    #    large held factor while they cost less than a new factorisation (fe_core.solvers.nearby).
    if NEARBY and A is not None:
        from .nearby import NearbySolver, pcg_budget

        for h in reversed(held):  # the newest factor first
            if h.pattern_digest == pattern and h.nnz_factor >= NEARBY_MIN_NNZ and h.pins == 0:
                budget = pcg_budget(h.factor_mflop, h.nnz_factor, h.last_lifetime_rhs)
                if budget >= MIN_PCG_SOLVES:
                    stats["nearby"] += 1
                    return _pinned(pool, h, NearbySolver(h, sp.csr_matrix(A, dtype=float), upper.data, digest,
                                                         budget, stats))
                break
    # 4. A numerical factorisation, on the oldest idle handle analysed for this pattern if there is one.
    idle = [h for h in pool if not h.pins and h.pattern_digest == pattern]
    if idle:
        h = idle[0]
        pool.remove(h)
    else:  # a new factor: large idle ones of other threads or thread counts make room first
        _release_other_pools(key)
        h = _Handle(upper.copy(), key, pattern, key[2])
    pool.append(h)
    if not h.factor(upper.data, digest):
        return None
    return _pinned(pool, h, h.solve)


def _changed_rows_sparse(upper: sp.csr_matrix, base: sp.csr_matrix):
    """As :func:`_changed_rows` for upper triangles of different patterns."""
    diff = sp.csr_matrix(upper - base)
    diff.eliminate_zeros()
    if diff.nnz == 0:
        return np.zeros(0, np.int64), np.zeros((0, 0))
    coo = diff.tocoo()
    R = np.unique(np.concatenate([coo.row, coo.col]))
    if R.size > MAX_LOW_RANK:
        return None
    pos = {r: k for k, r in enumerate(R)}
    D = np.zeros((R.size, R.size))
    for i, j, v in zip(coo.row, coo.col, coo.data):
        D[pos[i], pos[j]] += v
        if i != j:
            D[pos[j], pos[i]] += v
    return R, D


def _writable_into(out: np.ndarray, rhs: np.ndarray) -> bool:
    """Whether PARDISO may write the solution for ``rhs`` straight into ``out`` (not where the two overlap: PARDISO
    would read a right-hand side it is overwriting)."""
    return (out.shape == rhs.shape and out.dtype == np.float64 and out.flags.f_contiguous and out.flags.writeable
            and not np.may_share_memory(out, rhs))


def _pinned(pool: list, handle: _Handle, fn):
    """A solver reading ``handle``'s factor, which is not refactored while the solver lives; when the
    last such solver goes, the handle idles in the pool (the oldest idle beyond ``POOL_SIZE`` freed)."""
    if handle.pins == 0:
        handle.rhs_served = 0
    handle.pins += 1
    pool.remove(handle)
    pool.append(handle)  # the newest last

    def solve(rhs, out=None):
        """``A^-1 rhs``; with ``out`` (n x k), written there: straight from PARDISO when it is a Fortran-ordered
        float array (a block of a column-major basis), so no n x k copies of the solution are made."""
        if out is None:
            return fn(rhs)
        if fn == handle.solve:
            return handle.solve(rhs, out=out)
        out[...] = fn(rhs)
        return out

    def unpin():
        with _LOCK:
            handle.pins -= 1
            if not handle.pins:  # the workload of this lifetime: what the next one is expected to need
                handle.last_lifetime_rhs = handle.rhs_served
            if _POOL.get(handle.key) is not pool and not handle.pins and handle in pool:  # cleared meanwhile
                pool.remove(handle)
                handle.free()
            elif handle in pool:
                _trim(pool)

    solve.writes_into = True
    weakref.finalize(solve, unpin)
    return solve
