"""A reduced model for evaluating candidate effects exactly (not linearised): the full FE model projected once on
the Krylov space of one point, then every candidate, at any size and any stiffness factors, solved in that space.

With the space ``W`` (n x d) of :class:`fe_core.solvers.adjoint.ReducedResponse` at ``alpha0`` (``W^T K W =
diag(mu)``, ``W^T M W = I``), the projected segments ``S_i = W^T K_i W`` give the reduced stiffness at any alpha,
``K_r(alpha) = diag(mu) + sum_i (alpha_i - alpha0_i) S_i``, and a candidate effect adds its projected terms.

* **Low-rank effects** (a point mass, a grounded spring, the transducers' mass: unit terms that are ones on a few
  diagonal entries, :meth:`fe_core.closure.effects.Effect.diagonal`) add ``s U U^T`` with ``U = W[rows]^T``
  (d x q, q <= 3 a node). In the modal coordinates of ``K_r(alpha)`` the dynamic stiffness is diagonal,
  ``D0(w) = (1 + j w b) mu' - (w^2 - j w a)``, and Woodbury's identity gives the receptance with the effect at
  *every* size for the price of a q x q solve per line:
  ``Z(s) = Z0 - L (I / (c s) + G)^-1 R`` with ``G = U^T D0^-1 U``, ``L = l^T D0^-1 U``, ``R = U^T D0^-1 f`` and
  ``c = 1 + j w b`` (stiffness) or ``-(w^2 - j w a)`` (mass). :meth:`ReducedModel.scan` does this for many
  locations and sizes at once.
* **Any effect** (:meth:`ReducedModel.evaluate`): the reduced pencil with the effect's projected terms, one
  generalised eigenproblem of size d, with the exact derivatives of the reduced model for alpha and the effect's
  values (:meth:`ReducedModel.jacobian`).

The space holds the responses to the load and the sensor loads at ``alpha0``; a candidate far from there (another
alpha, a large mass) is a Galerkin approximation in it, good for ranking candidates and starting their fits; the
full FE model confirms what is kept (:func:`fe_core.closure.fits.fit_update`).
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ...solvers.adjoint import modal_sum, project_rows
from ...threads import thread_map
from ..effects import Applied, Effect
from ..effects.extended import segment_stiffness

__all__ = ["ReducedModel", "lowrank_factors", "Smoother"]


class ReducedModel:
    """The model at ``alpha0`` (with ``applied`` effects) projected on its Krylov space (see the module docstring),
    enlarged by the spaces of other points.

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : ndarray, shape (p,)
    alpha0 : ndarray, shape (m,)
    applied : sequence of Applied
        Effects in the model at the point (kept in the reduced model at their values).
    enrich : sequence of (alpha, applied)
        Other points whose Krylov spaces join the basis: where a search has fitted a large effect, the space there
        holds the local response round it that the first point's lacks (on the tet10 plate with a 4 % mass, the
        first point's space alone reproduced the truth's ``ln|Z|`` to 2.5 % rms from the nominal model).
    """

    def __init__(self, model, freqs_hz, alpha0, applied=(), enrich=()):
        from ..effects import extended_matrices
        from ..fast import full_response

        self.model = model
        self.freqs_hz = np.asarray(freqs_hz, float)
        self.omegas = 2 * np.pi * self.freqs_hz
        self.alpha0 = np.asarray(alpha0, float)
        self.applied = list(applied)
        lin = full_response(model, self.alpha0, self.freqs_hz, self.applied)
        red = lin.reduced
        self.a, self.b = float(red.a), float(red.b)
        self.gain = np.asarray(lin.gain, float)
        if not enrich:
            W, mu = red.W, np.asarray(red.mu, float)
            left, right = np.asarray(red.left, float), np.asarray(red.right, float)
        else:
            spaces = [red.W] + [full_response(model, np.asarray(a, float), self.freqs_hz, list(ap)).reduced.W
                                for a, ap in enrich]
            K, M, _, _ = extended_matrices(model, self.alpha0, self.applied)
            W, mu = _joined(spaces, K, M)
            del K, M
            left = np.asarray((model.outputs.T @ W))
            right = W.T @ model.combined_load()
        self.W, self.mu = W, np.asarray(mu, float)
        self.left = np.asarray(left, float)                # (n_s, d)
        self.right = np.asarray(right, float)              # (d,)
        self.segments = [_sym(project_rows(segment_stiffness(model, i), self.W)) for i in range(model.n_segments)]
        self.d = self.mu.size
        self.V, self.k0 = None, None    # static vectors joined for one candidate (:meth:`with_local`)
        self._local = None
        self._local_lock = threading.Lock()
        self._modal_cache: dict = {}
        self._units: dict = {}

    # -- the local flexibility of a candidate's place (:mod:`.local`) -----------------------------------------
    @property
    def local(self):
        """The :class:`.local.LocalFlexibility` of this point (made on first use: one factorisation of K)."""
        from .local import LocalFlexibility

        if self.V is not None:
            raise ValueError("the local flexibility is of the model's own space, not of one bordered by it")
        with self._local_lock:
            if self._local is None:
                self._local = LocalFlexibility(self)
        return self._local

    def with_local(self, rows) -> "ReducedModel":
        """This reduced model with the static vectors of ``rows`` (free-DOF indices) joined to its space: a
        candidate at those rows is evaluated with its local flexibility (:mod:`.local`). Shares the basis."""
        out = ReducedModel.__new__(ReducedModel)
        out.__dict__.update(self.__dict__)
        parts = self.local.border(rows)
        out.V, out.k0, out.segments = parts["V"], parts["k0"], parts["segments"]
        out.left, out.right = parts["left"], parts["right"]
        out.d = out.k0.shape[0]
        out._local, out._modal_cache, out._units = None, {}, {}
        return out

    def basis_rows(self, rows) -> np.ndarray:
        """The basis at free-DOF ``rows`` (any integer array shape), the joined static vectors' columns last."""
        if self.V is None:
            return self.W[rows]
        return np.concatenate([self.W[rows], self.V[rows]], axis=-1)

    def project(self, A) -> np.ndarray:
        """``B^T A B`` of a sparse (n, n) change on the basis ``B`` (joined vectors included), through A's rows."""
        if self.V is None:
            return _sym(project_rows(A, self.W))
        A = sp.csr_matrix(A)
        rows = np.flatnonzero(np.diff(A.indptr))
        if rows.size == 0:
            return np.zeros((self.d, self.d))
        Ar = A[rows]
        return _sym(self.basis_rows(rows).T @ np.hstack([Ar @ self.W, Ar @ self.V]))

    # -- the reduced pencil ------------------------------------------------------------------------------------
    def stiffness(self, alpha) -> np.ndarray:
        """``K_r(alpha)``, shape (d, d)."""
        K = np.diag(self.mu) if self.k0 is None else self.k0.copy()
        for da, S in zip(np.asarray(alpha, float) - self.alpha0, self.segments):
            if da:
                K = K + da * S
        return K

    def modal(self, alpha):
        """Eigenvalues (d,) and M-orthonormal vectors (d, d) of ``(K_r(alpha), I)`` (cached for the last alpha)."""
        key = np.asarray(alpha, float).tobytes()
        hit = self._modal_cache.get(key)
        if hit is None:
            mu, q = sla.eigh(self.stiffness(alpha))
            self._modal_cache = {key: (mu, q)}
            hit = (mu, q)
        return hit

    def _c(self, matrix: str) -> np.ndarray:
        w = self.omegas
        return (1.0 + 1j * w * self.b) if matrix == "stiffness" else -(w**2 - 1j * w * self.a)

    def _d0(self, mu, da: float = 0.0, db: float = 0.0) -> np.ndarray:
        w = self.omegas[:, None]
        a, b = self.a + da, self.b + db
        return (1.0 + 1j * w * b) * mu[None, :] - (w**2 - 1j * w * a)

    # -- exact evaluation of any effect ------------------------------------------------------------------------
    def unit_terms(self, effect: Effect, location: str, index: int, alpha) -> tuple:
        """The projected ``(dK, dM, da, db, gain)`` of parameter ``index`` at a unit value (the terms are linear in
        the values) at ``alpha``. An effect whose terms scale with the segments' factors (a patch, a joint band:
        ``beta K_band(alpha)``, linear in alpha) is projected once at alpha = 0 and once per segment
        (:meth:`Effect.alpha_derivative`); everything is cached per effect and location."""
        key = (effect.kind, location, index)
        hit = self._units.get(key)
        if hit is None:
            m = self.model.n_segments
            zero = np.zeros(m)
            t = effect.derivative(zero, location, index)
            dK = None if t.stiffness is None else self.project(t.stiffness)
            dM = None if t.mass is None else self.project(t.mass)
            unit = np.zeros(effect.n_parameters)
            unit[index] = 1.0
            parts = []
            for i in range(m):
                extra = effect.alpha_derivative(zero, location, unit, i)
                parts.append(None if extra is None or extra.stiffness is None
                             else self.project(extra.stiffness))
            hit = self._units[key] = (dK, dM, t.damping_a, t.damping_b, t.gain, parts)
        dK, dM, da, db, gain, parts = hit
        if dK is not None and any(P is not None for P in parts):
            dK = dK + sum(a * P for a, P in zip(np.asarray(alpha, float), parts) if P is not None and a)
        return dK, dM, da, db, gain

    def alpha_parts(self, effect: Effect, location: str, values) -> list:
        """``d (terms) / d alpha_i`` projected, per segment (None where the effect does not depend on it)."""
        v = np.atleast_1d(np.asarray(values, float))
        out = [None] * self.model.n_segments
        for k, x in enumerate(v):
            self.unit_terms(effect, location, k, self.alpha0)
            for i, P in enumerate(self._units[(effect.kind, location, k)][5]):
                if P is not None:
                    out[i] = x * P if out[i] is None else out[i] + x * P
        return out

    def terms(self, effect: Effect, location: str, values, alpha) -> tuple:
        """The projected ``(dK, dM, da, db, gain)`` of an effect at ``values`` (the terms are linear in them)."""
        v = effect.check(location, values)
        dK = dM = gain = None
        da = db = 0.0
        for i, x in enumerate(v):
            uK, uM, ua, ub, ug = self.unit_terms(effect, location, i, alpha)
            dK = dK if uK is None else (x * uK if dK is None else dK + x * uK)
            dM = dM if uM is None else (x * uM if dM is None else dM + x * uM)
            gain = gain if ug is None else (x * ug if gain is None else gain + x * ug)
            da, db = da + x * ua, db + x * ub
        return dK, dM, da, db, gain

    def evaluate(self, alpha, extra=(), derivatives=()):
        """``ln(|Z| (1 + g))`` (p, n_s) of the reduced model at ``alpha`` with ``extra`` effects (Applied), and the
        derivatives (p * n_s, k) along ``derivatives``: a list of ``(dK, dM, da, db, dgain)`` projected changes
        (None entries skipped)."""
        K = self.stiffness(alpha)
        M = np.eye(self.d)
        a, b = self.a, self.b
        gain = self.gain.copy()
        for item in extra:
            dK, dM, da, db, g = self.terms(item.effect, item.location, item.values, alpha)
            if dK is not None:
                K = K + dK
            if dM is not None:
                M = M + dM
            a, b = a + da, b + db
            if g is not None:
                gain = gain + g
        mu, phi = sla.eigh(K, M)
        w = self.omegas
        g_ = 1.0 / ((1.0 + 1j * w * b)[:, None] * mu[None, :] - (w**2 - 1j * w * a)[:, None])  # (p, d)
        left = self.left @ phi                            # (n_s, d)
        right = phi.T @ self.right                        # (d,)
        Z = modal_sum(left, g_, right[None, :])  # (p, n_s), in two real products: no (p, n_s, d) array
        lnZ = np.log(np.abs(Z)) + np.log1p(gain)[None, :]
        if not derivatives:
            return lnZ, None
        v = g_ * right[None, :]                           # (p, d)
        cols = []
        for dK, dM, da, db, dgain in derivatives:
            dZ = np.zeros_like(Z)
            if dK is not None:
                A = phi.T @ dK @ phi
                dZ += (1.0 + 1j * w * b)[:, None] * modal_sum(left, g_, v.real @ A.T + 1j * (v.imag @ A.T))
            if dM is not None:
                A = phi.T @ dM @ phi
                dZ += -(w**2 - 1j * w * a)[:, None] * modal_sum(left, g_, v.real @ A.T + 1j * (v.imag @ A.T))
            if da or db:
                diag = (1j * w)[:, None] * (da + db * mu[None, :])
                dZ += modal_sum(left, g_, diag * v)
            col = np.real(-dZ / Z)
            if dgain is not None:
                col = col + (np.asarray(dgain, float) / (1.0 + gain))[None, :]
            cols.append(col.ravel())
        return lnZ, np.column_stack(cols)

    def alpha_derivatives(self, extra=()):
        """The projected changes of the segments (for :meth:`evaluate`'s ``derivatives``), with those of the
        ``extra`` effects (Applied) that scale with the segments' factors."""
        out = [S for S in self.segments]
        for item in extra:
            for i, P in enumerate(self.alpha_parts(item.effect, item.location, item.values)):
                if P is not None:
                    out[i] = out[i] + P
        return [(S, None, 0.0, 0.0, None) for S in out]

    # -- many low-rank candidates at many sizes ----------------------------------------------------------------
    def scan(self, alpha, U: np.ndarray, matrix: str, sizes: np.ndarray, log_u: np.ndarray,
             project: np.ndarray | None = None, chunk: int = 64, lines: np.ndarray | None = None,
             residual: np.ndarray | None = None) -> np.ndarray:
        """Sums of squares of ``ln|Z(s)| - log_u`` (with ``project``'s columns, orthonormal (p * n_s, k), projected
        out: alpha refitted linearly) for candidates ``U`` (N, d, q) at ``sizes`` (N, S) or (S,): shape (N, S).

        ``matrix``: "mass" or "stiffness" (the term ``s U U^T`` is added to that matrix). Exact in the reduced
        space (Woodbury's identity in the modal coordinates of ``K_r(alpha)``); ``residual`` (N, q, q), the
        candidates' local flexibility outside the space (:meth:`.local.LocalFlexibility.residual`), is added to
        their drive-point receptance ``G``."""
        lines = np.arange(self.omegas.size) if lines is None else np.asarray(lines)
        mu, q = self.modal(alpha)
        left = self.left @ q                               # (n_s, d)
        right = q.T @ self.right                           # (d,)
        inv = 1.0 / self._d0(mu)[lines]                    # (p, d)
        Z0 = np.einsum("sd,pd,d->ps", left, inv, right)
        X = left[None, :, :] * inv[:, None, :]             # (p, n_s, d): l^T D0^-1
        Y = inv * right[None, :]                           # (p, d): D0^-1 f
        c = self._c(matrix)[lines]                         # (p,)
        cb = self._c("stiffness")[lines]
        log_u = np.asarray(log_u)[lines]
        N = U.shape[0]
        sizes = np.asarray(sizes, float)
        sizes = np.broadcast_to(sizes, (N, sizes.shape[-1])) if sizes.ndim == 1 else sizes
        out = np.empty(sizes.shape)
        gain = np.log1p(self.gain)[None, :]
        p, n_s = Z0.shape

        def block(k0):  # one chunk of candidates at every size (independent of the others: on the threads)
            Uc = np.einsum("dk,ndq->nkq", q, U[k0:k0 + chunk])          # modal coordinates (n, d, q)
            G = np.einsum("ndq,pd,ndr->npqr", Uc, inv, Uc, optimize=True)
            if residual is not None:
                G = G + residual[k0:k0 + chunk, None] / cb[None, :, None, None]
            L = np.einsum("psd,ndq->npsq", X, Uc, optimize=True)
            R = np.einsum("ndq,pd->npq", Uc, Y, optimize=True)
            for j in range(sizes.shape[1]):
                s = sizes[k0:k0 + chunk, j]                                # (n,)
                with np.errstate(divide="ignore", invalid="ignore"):
                    shift = 1.0 / (c[None, :] * s[:, None])                # (n, p)
                shift = np.where(np.isfinite(shift), shift, 1e300)
                A = G + shift[:, :, None, None] * np.eye(G.shape[-1])[None, None]
                x = _solve_small(A, R)                                     # (n, p, q)
                Z = Z0[None] - np.einsum("npsq,npq->nps", L, x)
                r = (np.log(np.abs(Z)) + gain[None] - log_u[None]).reshape(len(s), -1)
                if project is not None:
                    r = r - (r @ project) @ project.T
                out[k0:k0 + chunk, j] = np.einsum("ni,ni->n", r, r)

        thread_map(block, range(0, N, chunk))
        return out

    def alpha_projector(self, alpha, lines: np.ndarray | None = None) -> np.ndarray:
        """Orthonormal basis (p * n_s, m) of the reduced model's ``d ln|Z| / d alpha`` at ``alpha`` (no effect), on
        ``lines`` (all by default)."""
        _, J = self.evaluate(alpha, derivatives=self.alpha_derivatives())
        if lines is not None:
            J = J.reshape(self.omegas.size, -1, J.shape[1])[np.asarray(lines)].reshape(-1, J.shape[1])
        qq, _ = np.linalg.qr(J)
        return qq


def lowrank_factors(reduced: ReducedModel, effect: Effect, locations) -> tuple[str, np.ndarray] | None:
    """``(matrix, U)`` with U (L, d, q) of a diagonal effect at ``locations`` (rows of the basis at its DOFs; a
    missing DOF gives a zero column), or None for an effect that is not diagonal."""
    if effect.n_parameters != 1:
        return None
    diag = effect.diagonal(list(locations))
    if diag is None:
        return None
    matrix, rows = diag
    rows = np.atleast_2d(np.asarray(rows, np.int64))
    U = reduced.basis_rows(np.maximum(rows, 0))             # (L, q, d)
    U = np.where((rows >= 0)[:, :, None], U, 0.0)
    return matrix, np.ascontiguousarray(U.transpose(0, 2, 1))


def _solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve many small systems ``A x = b`` (A (..., q, q), b (..., q)); Cramer's rule for q <= 3 (LAPACK's
    batched solve costs 5 us a 3 x 3 system, the closed form a tenth)."""
    q = A.shape[-1]
    if q == 1:
        return b / A[..., 0, :]
    if q == 2:
        a11, a12, a21, a22 = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
        det = a11 * a22 - a12 * a21
        return np.stack([(a22 * b[..., 0] - a12 * b[..., 1]) / det, (a11 * b[..., 1] - a21 * b[..., 0]) / det], -1)
    if q == 3:
        a, b_, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
        d, e, f = A[..., 1, 0], A[..., 1, 1], A[..., 1, 2]
        g, h, i = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
        c11, c12, c13 = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * c11 + b_ * c12 + c * c13
        y0, y1, y2 = b[..., 0], b[..., 1], b[..., 2]
        x0 = (c11 * y0 + (c * h - b_ * i) * y1 + (b_ * f - c * e) * y2) / det
        x1 = (c12 * y0 + (a * i - c * g) * y1 + (c * d - a * f) * y2) / det
        x2 = (c13 * y0 + (b_ * g - a * h) * y1 + (a * e - b_ * d) * y2) / det
        return np.stack([x0, x1, x2], -1)
    return np.linalg.solve(A, b[..., None])[..., 0]


def _joined(spaces, K, M, block: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The Ritz vectors ``W`` (n, d) and values of ``(K, M)`` on the span of ``spaces`` (arrays (n, d_i)), columns
    scaled to unit length, orthonormalised by QR (dependent directions, ``|R_ii|`` under 1e-8 of the largest,
    dropped). Two (n, d) arrays at a time, never more: the columns joined (then overwritten by the QR) and its Q,
    then Q and ``W``; ``K Q`` and ``M Q`` go by blocks of columns. At 500k DOFs one such array is 1.1 GB, and the
    plain ``hstack``/``qr``/``K @ V`` chain held six beside the model (the exact search's second pass took the
    flow's process past 21 GB)."""
    n, k = spaces[0].shape[0], sum(x.shape[1] for x in spaces)
    X = np.empty((n, k), order="F")
    j = 0
    for x in spaces:
        np.divide(x, np.maximum(np.linalg.norm(x, axis=0), 1e-300), out=X[:, j:j + x.shape[1]])
        j += x.shape[1]
    Q, R = sla.qr(X, mode="economic", overwrite_a=True, check_finite=False)
    del X
    keep = np.abs(R.diagonal()) > 1e-8 * np.abs(R.diagonal()).max()
    if not keep.all():
        Q = Q[:, keep]
    d = Q.shape[1]
    Kr, Mr = np.empty((d, d)), np.empty((d, d))
    for j in range(0, d, block):
        part = Q[:, j:j + block]
        Kr[:, j:j + block] = Q.T @ (K @ part)
        Mr[:, j:j + block] = Q.T @ (M @ part)
    mu, phi = sla.eigh(_sym(Kr), _sym(Mr))
    return Q @ phi, np.asarray(mu, float)


def _sym(A) -> np.ndarray:
    A = np.asarray(A, float)
    return 0.5 * (A + A.T)


class Smoother:
    """Lorentzian smoothing of a power spectrum along frequency, the same for the model and the data:
    ``S[P](f_k) = sum_j w_kj P(f_j) / sum_j w_kj``, ``w_kj = 1 / (1 + ((f_j - f_k) / (width f_k))^2)`` within
    ``reach`` half-widths. A resonance's power (a Lorentzian of half-width ``zeta f_n``) convolved with it is a
    Lorentzian of half-width ``(zeta + width) f_n``: as if damped by ``width`` more, for model and data alike, so a
    mode misplaced by a few bandwidths is still within reach of a local fit. ``width = 0`` is no smoothing."""

    def __init__(self, freqs_hz, width: float, reach: float = 6.0):
        import scipy.sparse as sp

        f = np.asarray(freqs_hz, float)
        self.width = float(width)
        if width <= 0:
            self.S = None
            return
        rows, cols, vals = [], [], []
        for k, fk in enumerate(f):
            h = width * fk
            near = np.flatnonzero(np.abs(f - fk) <= reach * h)
            w = 1.0 / (1.0 + ((f[near] - fk) / h) ** 2)
            rows += [k] * near.size
            cols += near.tolist()
            vals += (w / w.sum()).tolist()
        self.S = sp.csr_matrix((vals, (rows, cols)), shape=(f.size, f.size))

    def log_amplitude(self, log_amp: np.ndarray) -> np.ndarray:
        """``ln sqrt(S[|Z|^2])`` of ``ln|Z|`` (p, n) or (..., p, n)."""
        if self.S is None:
            return log_amp
        P = np.exp(2.0 * log_amp)
        if P.ndim == 2:
            return 0.5 * np.log(self.S @ P)
        shape = P.shape
        Q = np.moveaxis(P, -2, 0).reshape(shape[-2], -1)
        out = (self.S @ Q).reshape((shape[-2],) + shape[:-2] + (shape[-1],))
        return 0.5 * np.log(np.moveaxis(out, 0, -2))

    def jacobian(self, log_amp: np.ndarray, J: np.ndarray) -> np.ndarray:
        """Derivatives of :meth:`log_amplitude` from those of ``ln|Z|`` (J: (p * n, k), frequency-major)."""
        if self.S is None:
            return J
        p, n = log_amp.shape
        P = np.exp(2.0 * log_amp)                          # (p, n)
        SP = self.S @ P
        Jr = J.reshape(p, n, -1)
        num = (self.S @ (P[:, :, None] * Jr).reshape(p, -1)).reshape(p, n, -1)
        return (num / SP[:, :, None]).reshape(p * n, -1)
