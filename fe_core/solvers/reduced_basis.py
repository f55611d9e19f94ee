"""A global parametric reduced basis for the Gauss-Newton rounds of a large model (issue 41).

An FE run with its Jacobian builds a block Krylov space of ``K(alpha)^-1 M`` from the load and the sensors'
output vectors (:func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives`): ~143 vectors at 150k DOFs,
grown with a factorisation of ``K(alpha)``. The model is affine in its parameters,

    K(alpha) = K_0 + sum_i (1 + alpha_i) K_i,    M(gamma) = M_0 + sum_j (1 + gamma_j) M_j,

so once every segment matrix is projected on a basis V (n x r), ``V^T K(alpha) V`` at any other point is a
sum of r x r matrices: the Galerkin-reduced model, its FRFs and its exact Jacobian (the same formula as the
full-order run's, :func:`fe_core.solvers.frf_derivatives.projected_response`) cost r x r work, with no
factorisation (a global parametric basis: Benner, Gugercin & Willcox, SIAM Review 57, 2015, section 4; the
bases of several parameter points are concatenated, "greedy" enrichment where the reduced model is not good
enough: Quarteroni, Manzoni & Negri, Reduced Basis Methods, 2016, ch. 7).

**Derivative enrichment.** A basis of the points visited so far reproduces a point a Gauss-Newton step of 0.1-0.3
away badly (the 37k-DOF panel of ``benchmarks.make.large``: responses 3-27 % off, the Jacobian 6-52 %), which is
why only the end-game's rounds were served. The Krylov space's own derivative along a parameter is
``d(K^-1 b)/d alpha_i = -K^-1 K_i K^-1 b``: so when the basis is started, the first :data:`DERIVATIVE_BLOCKS`
blocks of the first space ``W`` are differentiated along every parameter's part, ``K0^-1 A_i W[:, :c]`` (one solve
per column with the check's preconditioner, K factored at that point), and added (a Hermite-type parametric basis: Benner, Gugercin &
Willcox 2015, section 4.1). On that panel (143 columns, 26 per parameter, 351 in all) the responses at those steps
are then good to 1.5e-4-1.5e-3 and the Jacobian to 2e-4-2.3e-3, and Gauss-Newton on the reduced model alone
reaches the full-order optimum (``python -m benchmarks.basis_enrichment``).

**The check.** Whether the reduced model is good at a point is decided from the full-order residual of its
solutions, ``r(w) = D(w) V y(w) - b`` for the load (primal) and every sensor (dual, ``b = l_s``), at every
line, preconditioned by the factor of K at the point the basis was started from: ``z = K0^-1 r``, the error
``e = D^-1 r`` up to ``mu / (mu - lambda)`` in each mode (about 1 off resonance, the quality factor at one),
the measure :mod:`fe_core.solvers.nearby` stops its iterations on. Its norm is taken through a random sketch:
``S z = Y^T r`` with ``Y = K0^-1 S^T`` (:data:`SKETCH_ROWS` solves, once), ``S`` a sparse sign embedding
(:data:`SKETCH_NONZEROS` random signs per column: the norm of any fixed vector kept to ~sqrt(2/k); Balabanov &
Nouy, Adv. Comput. Math. 45, 2019, "Randomized linear algebra for model reduction. Part I", their sketched
residual-based error indicator). ``Y^T K_t V`` and ``Y^T M_t V`` are kept (k x r per segment), so a line costs
k x r work, never n. The estimate of each field's relative error is
``kappa(w) ||S z|| / ||V y||`` with ``kappa = max(1, max_i |mu_i / (mu_i - lambda(w))|)`` over the reduced
pencil's eigenvalues (``lambda = (w^2 - j w a) / (1 + j w b)``; the modes of the band are in the space); a
point is served when it is at most :data:`FIELD_TOL` at every line. Measured (tests/fe_core/test_reduced_basis.py,
docs/results/scaling.md): on the tet10 bracket the largest estimate is within 0.8-1.2 of the largest true
Jacobian error; on the benchmark's hex8 plates it is low by up to 40 (the Euclidean norm of z weighs the
fields' stiff, small-scale errors less than the Jacobian, an energy product, does; the energy norm of z would
need half-solves with the factor, and its bound by diag(K) was 6-130 times too high). That is why a
reduced point is never the last word:

A point not served is run at full order: a full-order FE run (the usual one: the held factor
preconditions it, :mod:`fe_core.solvers.nearby`) whose converged Krylov space is then added to V (enrichment:
orthogonalised against V twice, every segment matrix projected on the new columns). A point the basis served
reduced is run at full order when asked again: that is how a strategy confirms its final point
(:func:`strategies.hybrid_phases.local_phase`).

Only for models of :data:`MIN_DOFS` to :data:`MAX_DOFS` free DOFs (small models keep their arithmetic bit for
bit; up to the size where :data:`MIN_COLUMNS` columns fit in :data:`MAX_BYTES`, 721k DOFs), only in
the process that runs a large model's single FE runs (``tasks/fe_runs.py``); ``MRGP_REDUCED_BASIS=0`` turns it
off. Plain numpy/scipy.
"""

from __future__ import annotations

import functools
import logging
import os
import time

import numpy as np
import scipy.sparse as sp

from . import frf, recycle
from .columns import SPREAD, orthonormalise, solve_into, touched_rows
from .frf import hz_to_rad
from .sketch import SKETCH_NONZEROS, SKETCH_ROWS, Estimate, sketched_estimate, sparse_sign_sketch
from .frf_derivatives import projected_response
from .sensitivity import frf_jacobian as full_frf_jacobian, segment_directions

__all__ = ["MIN_DOFS", "MAX_DOFS", "ENABLED", "FIELD_TOL", "SKETCH_ROWS", "SKETCH_NONZEROS", "MAX_DIMENSION",
           "ParametricBasis", "Estimate", "sparse_sign_sketch", "active", "frf_jacobian", "forget", "basis_of",
           "enrich_derivatives", "DERIVATIVE_BLOCKS", "basis_bytes", "MIN_COLUMNS", "EXACT_TOL"]

log = logging.getLogger(__name__)

#: Models with at least this many free DOFs use a global basis (tests lower it on the model: ``_reduced_min``).
MIN_DOFS = 50_000
#: ``MRGP_REDUCED_BASIS=0`` turns the global basis off.
ENABLED = os.environ.get("MRGP_REDUCED_BASIS", "1") != "0"
#: Largest estimated relative error of each primal and dual field at any line. The Jacobian's error is first
#: order in it, the responses' second order (both sides are in the space). A served round is never the last
#: word: the local phase confirms its centre by a full-order run, its responses and its Jacobian's step
#: (:func:`strategies.hybrid_phases.local_phase`), so the tolerance only has to keep Gauss-Newton's rounds
#: useful. Measured on the 37k-DOF panel with derivative enrichment (``python -m benchmarks.basis_enrichment``):
#: estimates of 1.4e-3 to 2.2e-2 at steps of 0.02 to 0.3 went with responses good to 6e-6 to 1.5e-3 of each line's
#: largest and the Jacobian to 4e-5 to 2.3e-3. On the benchmark's hex8 plates the estimate runs low, by up to 40
#: for the Jacobian: a round served there may step less well, and the confirmation catches it.
FIELD_TOL = 3e-2
#: A served point whose estimate is at most this is as good as a full-order run, and is reported as one (not
#: confirmed again): its Jacobian is off by at most ~40 times the estimate (the check's largest underestimate,
#: on hex8 plates), 4e-4, which moves Gauss-Newton's fixed point by at most 4e-4 sqrt(N) standard deviations for
#: N residual values (0.03 at the 500k panel's 7,200; the local phase stops at 0.1), and its responses by the
#: square. The usual case: the point after a confirmation, served from a basis restarted from that run's own
#: space (6.5e-6 on the 500k panel), which a second confirmation (a full-order run, 2-3 min there) re-ran.
EXACT_TOL = 1e-5
#: The basis holds at most this many columns, and at most MAX_BYTES of them (n x 8 bytes a column: 373
#: columns at 500k DOFs); a full-order space that does not fit restarts V from that space alone (kept full, the
#: 500k update's basis of its first three points refused every later round: docs/results/scaling.md).
MAX_DIMENSION = 720
MAX_BYTES = 1.5e9
#: Fewer columns than this in MAX_BYTES and the basis cannot hold a full-order run's space (~143 columns on the
#: large example) with one derivative block per parameter (9 x 13): larger models run every round at full order.
#: History (docs/results/scaling.md): at 500k DOFs a plain basis of 373 columns served only the end-game's rounds
#: (10.8 GB against 7.0); with derivative enrichment (da7b959) it served 7 of 10 rounds but its start (the
#: projections reading all of V once per part and block of 16 columns, ten parts) took 3-4 minutes and each
#: extension a minute: 1052 s against 906 s without it, so it was kept below 260k DOFs (720 columns). A segment's
#: projection now reads only its own rows of V, once per extension (:meth:`ParametricBasis.extend`).
MIN_COLUMNS = 260
MAX_DOFS = int(MAX_BYTES // (8 * MIN_COLUMNS))
#: A new space's direction joins V when at least this fraction of it lies outside V (the singular values of the
#: new columns orthogonalised against V, relative to the largest column): what is dropped changes the fields by
#: less than this, far below FIELD_TOL, and a nearby point's space, mostly in V already, adds only what is new
#: (n x columns of memory, and each column costs a product with every segment matrix and with V).
ENRICH_TOL = 1e-6
#: Columns per block of the enrichment's n-sized temporaries (n x 16 doubles: 62 MB at 500k DOFs).
BLOCK = 16
#: Derivative enrichment (module docstring): when the basis is started, the first DERIVATIVE_BLOCKS blocks of the
#: space (a block: the loads and the sensors) are differentiated along every parameter, ``K0^-1 A_i W``.
DERIVATIVE_BLOCKS = 2
#: A point the basis served within this max-norm distance counts as asked again (module docstring).
SAME_POINT = 1e-12

_KEY = "_reduced_basis"


class ParametricBasis:
    """An orthonormal basis V with every segment matrix, the loads and the outputs projected on it.

    Parameters
    ----------
    stiffness, mass : list of sparse (n, n); a mass part may be a function returning one (touching every row)
        The affine parts: ``K = sum_t w_t stiffness[t]``, ``M = sum_t v_t mass[t]`` (the weights are given
        at evaluation: ``1 + alpha_i`` for a segment, 1 for a fixed part).
    loads : ndarray, shape (n, n_loads)
    outputs : sparse or ndarray, shape (n, n_out)
    sketch : sparse, shape (k, n), optional
        :func:`sparse_sign_sketch` by default.
    capacity : int
        Columns allocated (column-major: only the columns written take memory).

    Attributes
    ----------
    dim : int
        Columns in V.
    """

    def __init__(self, stiffness, mass, loads, outputs, precondition, sketch=None, capacity: int = MAX_DIMENSION):
        self.stiffness, self.mass = list(stiffness), list(mass)
        self.parts = self.stiffness + self.mass
        n = self.stiffness[0].shape[0]
        # The rows each part touches (a segment's DOFs: a ninth of the panel's): its projections read only those
        # rows of V, once per extension (:meth:`extend`); None where it touches most of them (the mass, a fixed part,
        # and a part given as a function: the whole structure's M, not assembled here only to find that out).
        self.rows = [None if callable(A) else touched_rows(A) for A in self.parts]
        S = sparse_sign_sketch(n) if sketch is None else sketch
        # The sketch of the preconditioned residual: S K0^-1 r = Y^T r with Y = K0^-1 S^T (k solves, once).
        self.sketch = np.ascontiguousarray(np.asarray(precondition(S.T.toarray()), dtype=float).T)  # (k, n)
        B = np.asarray(loads, dtype=float).reshape(n, -1)
        L = outputs.toarray() if sp.issparse(outputs) else np.asarray(outputs, dtype=float).reshape(n, -1)
        self.n_loads = B.shape[1]
        self.rhs = np.hstack([B, L])  # (n, c): the primal loads, then the dual ones
        self.S_rhs = self.sketch @ self.rhs  # (k, c)
        self.capacity = capacity
        self.V = np.empty((n, capacity), order="F")
        self.dim = 0
        self.R = np.zeros((len(self.parts), capacity, capacity))  # V^T A_t V
        self.SAV = np.zeros((len(self.parts), self.sketch.shape[0], capacity))  # S A_t V
        self.Vrhs = np.zeros((capacity, self.rhs.shape[1]))  # V^T [B, L]
        self.served: list[np.ndarray] = []  # points evaluated reduced (asked again: full order)
        self.pending: np.ndarray | None = None  # a full-order run's space, joined when another point is asked

    def restart(self) -> None:
        """Empty V (its memory is reused); the sketch ``Y = K0^-1 S^T`` stays (any fixed K0 preconditions the
        check). The newest spaces are the ones near where Gauss-Newton goes on."""
        self.dim = 0
        self.served = []

    def release(self) -> None:
        """Empty V and give its memory back (:meth:`restart` keeps the pages written): before a confirmation's
        full-order run, whose own space then starts V again (the sketch stays). A confirmation is asked at the
        local phase's centre, and what follows is a step from there that its space serves; holding V's columns
        through that run was the 500k update's peak (10.9 GB, against 8.7 without a basis)."""
        n = self.V.shape[0]
        self.V = None  # the old array freed before the new one is allocated
        self.V = np.empty((n, self.capacity), order="F")
        self.dim = 0
        self.served = []

    def join(self) -> int:
        """Add the :attr:`pending` space (restarting V from it when it does not fit); returns the columns added.

        A full-order run's space is joined when the basis is next asked for another point, not when the run ends:
        the run that confirms the local phase's centre is the last the basis sees, and its extension (orthogonalised
        against V, every part projected on it: a minute at 500k DOFs) would be spent for nothing."""
        W, self.pending = self.pending, None
        if W is None:
            return 0
        if self.dim + W.shape[1] > self.capacity:
            self.restart()  # full: V starts again from this space (the sketch and its solves kept)
        added = self.extend(W)
        log.info("reduced basis: %d of a full-order run's %d columns added, %d in all (at most %d)", added,
                 W.shape[1], self.dim, self.capacity)
        return added

    def extend(self, W: np.ndarray) -> int:
        """Add the part of ``W`` (n x s) not yet in V; returns the columns added (0 when V is full).

        Lean in memory: ``W`` (the caller's space is the recycled seed, left untouched) is copied into V's next
        columns and joined there (:meth:`absorb`) when it fits, else orthonormalised in one n x s copy.
        """
        d, s = self.dim, W.shape[1]
        if d >= self.capacity:
            return 0
        if d + s <= self.capacity:
            self.V[:, d:d + s] = W
            return self.absorb(s)
        Q = np.array(W, dtype=float, order="F")
        k = self._orthonormal(Q, d)
        self.V[:, d:d + k] = Q[:, :k]
        del Q
        self._project(d, k)
        return k

    def absorb(self, s: int) -> int:
        """Join the ``s`` columns written in V's next columns (``V[:, dim:dim + s]``): the part of them not yet in V,
        orthonormalised in place (against V by blocks of :data:`BLOCK` columns, then by their Gram matrix:
        :func:`fe_core.solvers.columns.orthonormalise`), every part projected on it; returns the columns added.
        Every n-sized temporary is a block of rows or columns (at 500k DOFs the whole-space temporaries of the plain
        formulas were 0.6 GB each, three at once). All of the derivative columns are joined in one call
        (:func:`enrich_derivatives`): V is read once for them, not once per parameter."""
        d = self.dim
        k = self._orthonormal(self.V[:, d:d + s], d)
        self._project(d, k)
        return k

    def _orthonormal(self, Q: np.ndarray, d: int) -> int:
        """Q (n x s, in V's next columns or a copy) orthonormalised against V's first d columns and within itself,
        in place; returns the k <= capacity - d directions kept (Q's first k columns)."""
        scale = max(1.0, float(np.sqrt(np.einsum("ij,ij->j", Q, Q).max(initial=0.0))))  # no n x s temporary
        self._orthogonalise(Q, d)
        k, spread = orthonormalise(Q, ENRICH_TOL * scale)
        k = min(k, self.capacity - d)
        if k > 0 and spread > SPREAD:  # the kept columns once more: orthonormal (and orthogonal to V) to round-off
            self._orthogonalise(Q[:, :k], d, passes=1)
            k, _ = orthonormalise(Q[:, :k], 0.5)
        return k

    def _project(self, d: int, k: int) -> None:
        """Every part, the sketch and the loads projected on V's new columns ``d:d + k``; V then has d + k."""
        if k <= 0:
            return
        V = self.V[:, :d + k]
        for t, part in enumerate(self.parts):
            A = _matrix(part)  # a part given as a function is assembled here, and dropped after
            rows = self.rows[t]
            # V's rows the part touches, gathered once per part (reading V once per part and block was the
            # extension's cost at 500k DOFs: memory traffic, ten parts x n x r doubles a block of 16 columns)
            Vt = V if rows is None else V[rows]
            St = self.sketch if rows is None else self.sketch[:, rows]
            for j in range(d, d + k, BLOCK):
                e = min(j + BLOCK, d + k)
                P = A @ self.V[:, j:e]
                if rows is not None:
                    P = P[rows]
                col = Vt.T @ P
                self.R[t, :d + k, j:e] = col
                self.R[t, j:e, :d + k] = col.T
                self.SAV[t, :, j:e] = St @ P
            del Vt, St, A
        for j in range(d, d + k, BLOCK):
            e = min(j + BLOCK, d + k)
            self.Vrhs[j:e] = self.V[:, j:e].T @ self.rhs
        self.dim = d + k

    def _orthogonalise(self, Q: np.ndarray, d: int, passes: int = 2) -> None:
        """Q minus its part in V's first d columns, in place, a block of :data:`BLOCK` columns at a time."""
        if not d:
            return
        for j in range(0, Q.shape[1], BLOCK):
            block = Q[:, j:j + BLOCK]
            for _ in range(passes):  # twice is enough (Giraud et al. 2005): V stays orthonormal to round-off
                block -= self.V[:, :d] @ (self.V[:, :d].T @ block)

    def evaluate(self, w_stiff, w_mass, a: float, b: float, omegas, k_dirs, m_dirs):
        """The reduced responses at every line and the check (:class:`Estimate`).

        Parameters
        ----------
        w_stiff, w_mass : ndarray
            Weights of the stiffness and mass parts.
        a, b : float
            Rayleigh coefficients.
        omegas : ndarray, shape (p,), rad/s
        k_dirs, m_dirs : list of int
            The parameters' parts: direction i is ``stiffness[k_dirs[i]]`` for the stiffness factors, then
            ``mass[m_dirs[j]]`` for the updated masses.

        Returns
        -------
        Z : ndarray, shape (p, n_out, n_loads)
        dZ : ndarray, shape (p, n_out, n_loads, len(k_dirs) + len(m_dirs))
        Estimate
        """
        self.join()
        d, nk = self.dim, len(self.stiffness)
        R = self.R[:, :d, :d]
        Kr = np.tensordot(np.asarray(w_stiff, float), R[:nk], axes=1)
        Mr = np.tensordot(np.asarray(w_mass, float), R[nk:], axes=1)
        stack = np.stack([Kr, Mr, *(R[t] for t in k_dirs), *(R[nk + t] for t in m_dirs)])
        n_k = len(k_dirs)
        m = n_k + len(m_dirs)
        k_index = {i: 2 + i for i in range(n_k)}
        m_index = {n_k + j: 2 + n_k + j for j in range(len(m_dirs))}
        omegas = np.asarray(omegas, dtype=float)
        lam = (omegas**2 - 1j * omegas * a) / (1.0 + 1j * omegas * b)
        scale = 1.0 / (1.0 + 1j * omegas * b)
        VF, VL = self.Vrhs[:d, :self.n_loads], self.Vrhs[:d, self.n_loads:]
        Z, dZ, (mu, phi) = projected_response(stack, VF, VL, k_index, m_index, np.zeros(m), np.zeros(m), m,
                                              omegas, a, b, lam, scale)
        return Z, dZ, self._estimate(Z, mu, phi, w_stiff, w_mass, lam, scale)

    def _estimate(self, Z, mu, phi, w_stiff, w_mass, lam, scale) -> Estimate:
        d, nk = self.dim, len(self.stiffness)
        return sketched_estimate(self.SAV[:, :, :d], self.Vrhs[:d], self.S_rhs, nk, w_stiff, w_mass, mu, phi, lam,
                                 scale, FIELD_TOL)


def active(model) -> bool:
    """Whether a large model's single FE runs may use a global basis: from :data:`MIN_DOFS` free DOFs up to the
    size at which :data:`MIN_COLUMNS` columns still fit in :data:`MAX_BYTES` (721k DOFs)."""
    n = getattr(model, "n_dofs", 0)
    return ENABLED and model.__dict__.get("_reduced_min", MIN_DOFS) <= n <= MAX_DOFS


def basis_bytes(n_dofs: int) -> float:
    """The memory a model of ``n_dofs`` free DOFs gives its global basis (0 where none is used): V's columns and the
    enrichment's n-sized temporaries (one space's copy, a block per part)."""
    if not (ENABLED and MIN_DOFS <= n_dofs <= MAX_DOFS):
        return 0.0
    return 8.0 * n_dofs * (min(MAX_DIMENSION, MAX_BYTES // (8 * n_dofs)) + 2 * BLOCK)


def basis_of(model):
    """The model's global basis (None before its first full-order run)."""
    return model.__dict__.get(_KEY)


def forget(model) -> None:
    """Drop the model's basis (its memory: n x dim)."""
    model.__dict__.pop(_KEY, None)


def _parts(model):
    """The affine stiffness and mass parts and the parameters' positions among them."""
    dirs = segment_directions(model)
    ns = model.n_segments
    stiffness = [d.stiffness for d in dirs[:ns]]
    if model.stiffness_segments.has_fixed:
        stiffness.append(model.stiffness_segments.own(ns))
    if model.mass_parameters.size:
        mass = [model.mass_segments.own(i) for i in range(ns)]
        if model.mass_segments.has_fixed:
            mass.append(model.mass_segments.own(ns))
    else:  # no updated mass: M is one fixed part, assembled when V is extended (not held: 0.29 GB at 500k DOFs)
        mass = [functools.partial(model.mass, None)]
    return stiffness, mass


def _matrix(part):
    """A basis part: a sparse matrix, or a function assembling it (:func:`_parts`)."""
    return part() if callable(part) else part


def enrich_derivatives(basis: ParametricBasis, W: np.ndarray, solve, directions) -> int:
    """Add ``solve(A_i @ W[:, :c])`` for every parameter part ``A_i`` of ``directions`` (module docstring:
    derivative enrichment); ``c`` is :data:`DERIVATIVE_BLOCKS` blocks of the space's width (the loads and the
    sensors), fewer where the basis's capacity would not hold them all. The solves are written in V's next columns
    and joined in one pass (at 500k DOFs, joined one parameter at a time, they took 50 s: V read for each).
    Returns the columns added."""
    width = basis.rhs.shape[1]
    room = (basis.capacity - basis.dim) // max(1, len(directions))
    c = min(DERIVATIVE_BLOCKS * width, W.shape[1], room)
    if c <= 0:
        return 0
    head = W[:, :c]
    d = basis.dim
    t0 = time.perf_counter()
    for i, A in enumerate(directions):  # written in V's next columns, joined at once (ParametricBasis.absorb)
        solve_into(solve, A @ head, basis.V[:, d + i * c:d + (i + 1) * c])
    t1 = time.perf_counter()
    added = basis.absorb(c * len(directions))
    solving, joining = t1 - t0, time.perf_counter() - t1
    log.info("reduced basis: %d derivative directions of %d columns each: solves %.1f s, joined in %.1f s",
             len(directions), c, solving, joining)
    return added


def _weights(model, alpha, gamma):
    ws = 1.0 + np.asarray(alpha, float)
    if model.stiffness_segments.has_fixed:
        ws = np.append(ws, 1.0)
    if not model.mass_parameters.size:
        return ws, np.ones(1)
    wm = 1.0 + np.asarray(gamma, float)
    return ws, (np.append(wm, 1.0) if model.mass_segments.has_fixed else wm)


def frf_jacobian(model, theta, freqs_hz, channels=None):
    """:func:`fe_core.solvers.sensitivity.frf_jacobian` through the model's global basis where its check allows.

    Returns ``(Z, dZ, reduced)``: the receptance and its derivative as the full-order function returns them,
    and whether they came from the reduced model (False: a full-order run, whose space enriched the basis, or a
    point served with an estimate of at most :data:`EXACT_TOL`, as good as one). A model that is not
    :func:`active` always runs full order.
    """
    if not active(model):
        Z, dZ = full_frf_jacobian(model, theta, freqs_hz, channels=channels)
        return Z, dZ, False
    theta = np.asarray(theta, dtype=float)
    alpha, gamma = model.factors(theta)
    key = None if channels is None else (tuple(np.ravel(channels[0])), tuple(np.ravel(channels[1])))
    basis = basis_of(model)
    if basis is not None and basis.channels != key:  # other loads: another basis
        forget(model)
        basis = None
    usable = basis is not None and (basis.dim > 0 or basis.pending is not None)  # not after a failed confirmation
    again = basis is not None and any(np.max(np.abs(theta - x), initial=0.0) <= SAME_POINT for x in basis.served)
    if usable and not again:
        freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
        ws, wm = _weights(model, alpha, gamma)
        ns = model.n_segments
        m_dirs = [int(j) for j in model.mass_parameters]
        Z, dZ, est = basis.evaluate(ws, wm, *model.damping, hz_to_rad(freqs), list(range(ns)), m_dirs)
        if est.ok:
            largest = float(est.field_error.max())
            exact = largest <= EXACT_TOL
            if not exact:
                basis.served.append(theta.copy())
            responses, column = basis.pick
            log.info("reduced basis (%d columns): served (estimated field error %.1e%s)", basis.dim, largest,
                     ": as good as a full-order run" if exact else "")
            return Z[:, responses, column], dZ[:, responses, column, :], not exact
        log.info("reduced basis (%d columns): refused (estimated field error %.1e); a full-order run enriches it",
                 basis.dim, float(est.field_error.max()))
    if again:
        basis.pending = None
        basis.release()  # a confirmation: its space starts V again (ParametricBasis.release)
        log.info("reduced basis: released for the confirmation's full-order run; its space starts it again")
    space: dict = {}
    Z, dZ = full_frf_jacobian(model, theta, freqs_hz, channels=channels, space=space)
    W = space.get("basis")
    if W is None:
        return Z, dZ, False
    if basis is None:
        if channels is None:
            loads, responses, column = model.combined_load(), slice(None), 0
        else:
            loads, responses, column = model.channel_loads(*channels)
        # The preconditioner of the check: K at this point, factored (or held) by the run just made (M is not
        # assembled: its 0.3 GB at 500k DOFs would only serve a shifted factor, which gives no check).
        K = model.stiffness(alpha)
        banded, solve = frf.banded_cholesky(K)  # looked up when called: benchmarks count frf.spd_solver's calls
        solve = solve if banded else frf.spd_solver(K)
        del K
        if solve is None:  # K is not positive-definite (a free structure): no check, no basis
            return Z, dZ, False
        stiffness, mass = _parts(model)
        capacity = int(min(MAX_DIMENSION, MAX_BYTES // (8 * model.n_dofs)))
        t = [time.perf_counter()]
        basis = ParametricBasis(stiffness, mass, loads, model.outputs, solve, capacity=capacity)
        basis.channels, basis.pick = key, (responses, column)
        model.__dict__[_KEY] = basis
        t.append(time.perf_counter())
        added = basis.extend(W)
        # The first run's space is in V now. Kept as the recycled seed beside it, it would only seed a run within
        # recycle.MAX_STEP of this point, which the basis serves: dropped, and only the head the derivatives are
        # taken from kept (at 500k DOFs the space is 0.6 GB, and the derivative columns were the run's peak).
        recycle.forget(model)
        W = np.array(W[:, :DERIVATIVE_BLOCKS * basis.rhs.shape[1]])
        space.clear()
        t.append(time.perf_counter())
        derivative = enrich_derivatives(basis, W, solve, [stiffness[i] for i in range(model.n_segments)]
                                        + [mass[int(j)] for j in model.mass_parameters])
        t.append(time.perf_counter())
        del solve
        log.info("reduced basis: started from the full-order run's %d columns and %d derivative columns, %d in all "
                 "(at most %d); %.1f s: the check's sketch %.1f, the space %.1f, the derivatives %.1f", added,
                 derivative, basis.dim, basis.capacity, t[3] - t[0], *np.diff(t))
        return Z, dZ, False
    basis.join()  # an earlier run's space not yet joined (two full-order runs in a row)
    basis.pending = W  # the run's own space: joined when another point is asked (ParametricBasis.join)
    return Z, dZ, False
