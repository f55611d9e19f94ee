"""The reduced model the closure's fast fits run on (:mod:`.fast`): an orthonormal basis of full fields with the
model's matrices projected on it, and the receptance with its exact first derivatives evaluated there.

:class:`ReducedBasis` grows by the full Krylov spaces of the points the fits end at (Galerkin projection; a basis
holding the space at a point reproduces the full receptance and its first derivatives there); :class:`_ReducedModal`
is the modal algebra of :class:`fe_core.solvers.adjoint.ReducedResponse` on it, :class:`_ReducedLinearised` the
closure's :class:`fe_core.closure.effects.LinearisedResponse` interface on it (no FE solve).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..solvers.adjoint import ReducedResponse, modal_sum, project_rows
from .effects import LinearisedResponse, extended_matrices, sensor_gain
from .effects.extended import segment_stiffness

__all__ = ["ReducedBasis", "REMEMBER_ROWS"]

#: A change touching more rows than this (a segment's mass) is kept projected on the basis and reused for any
#: later change of the same pattern proportional to it (the same segment's mass at another factor).
REMEMBER_ROWS = 64

class ReducedBasis:
    """An orthonormal basis V of full fields and the model's matrices projected on it."""

    def __init__(self, model, freqs_hz):
        self.model = model
        self.freqs_hz = np.asarray(freqs_hz, float)
        m = model.n_segments
        K0, M, _, _ = extended_matrices(model, np.zeros(m))
        # The matrices kept projected, each with the rows it touches: the segments, K(alpha = 0), M.
        self._mats = [segment_stiffness(model, i) for i in range(m)] + [sp.csr_matrix(K0), sp.csr_matrix(M)]
        self._rows = [np.flatnonzero(np.diff(A.indptr)) for A in self._mats]
        self._proj = [np.zeros((0, 0)) for _ in self._mats]
        self.V = np.zeros((K0.shape[0], 0))
        self.holds: set = set()  # keys of the points whose full spaces the basis holds
        self._remembered: dict = {}  # pattern -> (values, V^T A V) of large changes on this basis
        self.segments: list[np.ndarray] = []
        self.fixed = None

    def add(self, W: np.ndarray):
        """Enlarge the basis by the span of W's columns (normalised, orthogonalised twice against V, kept
        where a pivoted QR finds them new to 1e-8) and extend the projections by the new rows and columns."""
        V = self.V
        X = np.array(W, dtype=float, copy=True)
        X /= np.maximum(np.linalg.norm(X, axis=0), np.finfo(float).tiny)
        for _ in range(2):
            X -= V @ (V.T @ X)
        q, r, _ = sla.qr(X, mode="economic", pivoting=True)
        keep = int(np.sum(np.abs(np.diag(r)) > 1e-8))
        Q = q[:, :keep]
        for t, (A, rows) in enumerate(zip(self._mats, self._rows)):
            AQ = (A @ Q)[rows]  # (rows, k): A's rows only
            cross = V[rows].T @ AQ  # (d, k)
            new = Q[rows].T @ AQ  # (k, k)
            P = self._proj[t]
            self._proj[t] = np.block([[P, cross], [cross.T, 0.5 * (new + new.T)]])
        self.V = np.hstack([V, Q])
        self._remembered = {}
        m = self.model.n_segments
        self.segments = self._proj[:m]
        self.fixed = self._proj[m] - sum(self.segments)  # K(alpha) = fixed + sum (1 + alpha_i) K_i
        self.mass = self._proj[m + 1]
        self.load = self.V.T @ self.model.combined_load()
        self.outputs = np.asarray(sp.csc_matrix(self.model.outputs).T @ self.V).T  # (d, n_s)

    def reset(self):
        """Empty the basis (the next :meth:`add` starts it afresh)."""
        self.V = self.V[:, :0]
        self._proj = [np.zeros((0, 0)) for _ in self._mats]
        self.holds = set()
        self._remembered = {}

    def project(self, A) -> np.ndarray:
        """``V^T A V`` of a sparse change through its non-empty rows; a change of more than
        ``REMEMBER_ROWS`` rows proportional to one projected before on this basis (same pattern, values a
        multiple to 1e-13) is that projection times the factor."""
        A = sp.csr_matrix(A)
        if np.count_nonzero(np.diff(A.indptr)) <= REMEMBER_ROWS:
            return project_rows(A, self.V)
        key = (A.shape, A.nnz, hash(A.indptr.tobytes()), hash(A.indices.tobytes()))
        held = self._remembered.get(key)
        if held is not None:
            values, P = held
            c = float(A.data @ values) / float(values @ values)
            if np.max(np.abs(A.data - c * values)) <= 1e-13 * np.max(np.abs(A.data)):
                return c * P
        P = project_rows(A, self.V)
        if np.any(A.data):  # a change whose stored values are all zero is no multiple to scale
            self._remembered[key] = (A.data.copy(), P)
        return P


class _ReducedModal(ReducedResponse):
    """:class:`ReducedResponse` on a given basis: the same modal algebra, no Krylov space."""

    def __init__(self, basis: ReducedBasis, Kr, Mr, a, b, omegas, gain):
        self.basis = basis
        self.omegas = w = np.asarray(omegas, float)
        self.a, self.b = float(a), float(b)
        self.gain = np.asarray(gain, float)
        mu, phi = sla.eigh(0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T))
        self.phi, self.mu = phi, mu
        lam = (w**2 - 1j * w * self.a) / (1.0 + 1j * w * self.b)
        self.g = 1.0 / ((1.0 + 1j * w * self.b)[:, None] * (mu[None, :] - lam[:, None]))
        self.left = basis.outputs.T @ phi  # (n_s, m)
        self.right = phi.T @ basis.load
        self.Z = np.einsum("sm,pm,m->ps", self.left, self.g, self.right)
        self._u = self.left[None, :, :] * self.g[:, None, :]
        self._v = self.g * self.right[None, :]

    def project(self, A) -> np.ndarray:
        """``W^T A W`` (modal coordinates, ``W = V phi``) of a sparse change: through the rows of ``W`` it touches
        (``3 r d^2``) when it has fewer than ``d / 2`` rows (an effect at a node), else through the basis (``2 d^3``)."""
        A = sp.csr_matrix(A)
        rows = np.flatnonzero(np.diff(A.indptr))
        if 2 * rows.size >= self.phi.shape[0]:
            return self.phi.T @ self.basis.project(A) @ self.phi
        V = self.basis.V
        return (V[rows] @ self.phi).T @ ((A[rows] @ V) @ self.phi)


class _ReducedLinearised(LinearisedResponse):
    """:class:`LinearisedResponse` evaluated on a :class:`ReducedBasis` (same interface, no FE solve)."""

    def __init__(self, basis: ReducedBasis, model, alpha, freqs_hz, applied=()):
        self.model = model
        self.alpha = np.asarray(alpha, float)
        self.freqs_hz = np.asarray(freqs_hz, float)
        self.omegas = 2 * np.pi * self.freqs_hz
        self.applied = list(applied)
        Kr = basis.fixed + sum((1.0 + a) * k for a, k in zip(self.alpha, basis.segments))
        Mr = basis.mass.copy()
        a, b = model.damping
        for item in self.applied:
            t = item.terms(self.alpha)
            if t.gain is not None:
                continue
            if t.stiffness is not None:
                Kr = Kr + basis.project(t.stiffness)
            if t.mass is not None:
                Mr = Mr + basis.project(t.mass)
            a += t.damping_a
            b += t.damping_b
        self.a, self.b, self.basis = a, b, basis
        self.gain = sensor_gain(model, self.alpha, self.applied)
        self.reduced = _ReducedModal(basis, Kr, Mr, a, b, self.omegas, self.gain)
        self.Z = self.reduced.Z

    def alpha_derivatives(self) -> np.ndarray:
        """``d ln|Z| / d alpha_i``, shape (p * n_s, m): ``ReducedResponse.dlog`` of each segment's projected
        stiffness ``dK``: ``u^T phi^T dK phi v`` as ``modal_sum(left, g, y)``, ``y = (phi v)^T dK phi`` per frequency,
        real and imaginary parts apart (a complex (p, n_s, d) ``phi u`` costs two to four times as much)."""
        red = self.reduced
        phi = red.phi
        vr, vi = red._v.real @ phi.T, red._v.imag @ phi.T  # (p, d): v taken back to the basis, real and imaginary
        p, d = vr.shape
        c = (1.0 + 1j * red.omegas * red.b)[:, None]
        cols = []
        for i in range(self.model.n_segments):
            dK = self.basis.segments[i]
            for item in self.applied:
                extra = item.effect.alpha_derivative(self.alpha, item.location, item.values, i)
                if extra is not None and extra.stiffness is not None:
                    dK = dK + self.basis.project(extra.stiffness)
            if d < 2 * p:  # the cheaper order of the products
                Q = dK.T @ phi
                y = vr @ Q + 1j * (vi @ Q)
            else:
                y = (vr @ dK.T) @ phi + 1j * ((vi @ dK.T) @ phi)
            dZ = c * modal_sum(red.left, red.g, y)
            cols.append(np.real(-dZ / red.Z).ravel())
        return np.column_stack(cols)
