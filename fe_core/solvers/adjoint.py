"""Sensor FRFs and their exact first derivatives for any change of (K, M, a, b), in one Krylov space.

With the dynamic stiffness ``D(w) = K - w^2 M + j w (a M + b K)``, the
model's load F and output vectors ``l_s``, the receptance is
``Z_s = l_s^T D^-1 F`` and, for a change ``dD``,
``dZ_s = -(D^-1 l_s)^T dD (D^-1 F)`` (D is complex symmetric: reciprocity).
Both fields lie in the block Krylov space of :func:`fe_core.solvers.frf.krylov_space`
started from the load *and* the sensor loads, ``V`` (n x d, d about 36 on the
benchmark). In the modal coordinates of the reduced pencil,
``W = V phi`` with ``W^T K W = diag(mu)``, ``W^T M W = I``, every field is
``W g(w) c`` with ``g = 1 / ((1 + j w b)(mu - lambda(w)))``, so

    dZ_s(w) = -sum_ij (W^T l_s)_i g_i(w) [W^T dD(w) W]_ij g_j(w) (W^T F)_j,

and ``W^T dD W`` needs only the rows the change touches: a point mass costs a
3 x d product, a segment's stiffness a few thousand rows. One factorisation
and a 7-load Krylov space (about 20 ms on the benchmark, against 16 ms for
the FRF alone) give the derivative for any number of parameters, where
forward differences cost one FRF per parameter.

The Galerkin projection reproduces any field inside its space, so with both
the primal and the dual solutions converged in ``V`` the derivative is that
of the FE model to the space's convergence (compared against central
differences of the direct solver in ``tests/fe_core/test_adjoint.py``).

The space is the same one :func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives`
differentiates on, grown by the same builder (:class:`fe_core.solvers.frf.BlockKrylov`,
the only one in the code base). Two front-ends remain because they answer
different questions: ``krylov_frf_derivatives`` takes its directions
(:class:`fe_core.solvers.frf_derivatives.Direction`) before the space is built and
grows the space until the derivatives along them stop changing, which suits a
Jacobian over a fixed parameter list; this class builds the space once,
converged on the responses to the load *and* to the sensor loads at the
outputs (the primal and dual fields the derivative is made of), and keeps its
modal coordinates, so that changes not known in advance are differentiated
afterwards at the price of a row-sparse projection: the closure screens
hundreds of candidate effects per fit (:meth:`diagonal_dlog`), and the sensor
gains enter ``ln|Z|`` directly. ``dlog`` takes the four parts of a
``Direction`` (``fe_core.closure.effects.Terms`` has them) and a gain change.
One reduced-model object serving both (space plus modal coordinates) is the
next step.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..threads import thread_map
from .frf import direct_frf, krylov_space

__all__ = ["ReducedResponse", "modal_sum", "project_rows", "DIAGONAL_CHUNK"]

#: Locations per block of :meth:`ReducedResponse.diagonal_dlog` (its memory: a (chunk, k, p, n_s) complex block).
DIAGONAL_CHUNK = 256


def modal_sum(left: np.ndarray, g: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``sum_m left[s, m] g[p, m] y[p, m]``, shape (p, n_s): a sensor's reading of a modal response ``g y`` per
    frequency, as two real products (``left`` is real, ``g y`` complex) instead of a complex sum over the
    (p, n_s, m) array ``u = left g``."""
    z = g * y
    return z.real @ left.T + 1j * (z.imag @ left.T)


def project_rows(A, W: np.ndarray) -> np.ndarray:
    """``W^T A W`` of a sparse (n, n) change, shape (m, m), reading only A's non-empty rows (an effect or a
    segment touches few)."""
    A = sp.csr_matrix(A)
    rows = np.flatnonzero(np.diff(A.indptr))
    if rows.size == 0:
        return np.zeros((W.shape[1],) * 2)
    return W[rows].T @ (A[rows] @ W)


class ReducedResponse:
    """The receptance at the sensors of one (K, M, a, b) and ``d ln|Z|`` for any change of it.

    Parameters
    ----------
    K, M : sparse, shape (n, n)
        Stiffness (N/m) and mass (kg) on the free DOFs.
    a, b : float
        Rayleigh coefficients (1/s, s).
    load : ndarray, shape (n,), N
        The excitation.
    outputs : sparse, shape (n, n_s)
        Output vectors ``l_s`` (a sensor reads ``l_s^T z``).
    omegas : ndarray, shape (p,), rad/s
    gain : ndarray, shape (n_s,), optional
        Relative amplitude factors of the sensors (compared amplitude ``|Z_s| (1 + g_s)``).

    Attributes
    ----------
    Z : ndarray, shape (p, n_s), complex, m/N
        The receptance *without* the gains.
    amplitude : ndarray, shape (p, n_s), m/N
        ``|Z| (1 + gain)``.
    """

    def __init__(self, K, M, a: float, b: float, load, outputs, omegas, gain=None):
        K, M = sp.csr_matrix(K), sp.csr_matrix(M)
        L = sp.csc_matrix(outputs)
        self.omegas = w = np.asarray(omegas, float)
        self.a, self.b = float(a), float(b)
        n_s = L.shape[1]
        out_rows = np.unique(L.indices)
        loads = np.column_stack([np.asarray(load, float), L.toarray()])
        space = krylov_space(K, M, a, b, loads, w, out_rows)
        V, Kr, Mr, info = space.basis, space.stiffness, space.mass, space.info
        self.info = info
        self.gain = np.zeros(n_s) if gain is None else np.asarray(gain, float)
        if not info.converged:  # keep the result right: direct solves, and a space of their fields
            fields = direct_frf(K, M, a * M + b * K, loads, w, np.arange(K.shape[0]))  # (p, n, loads)
            fields = fields.transpose(1, 0, 2).reshape(K.shape[0], -1)
            V = np.linalg.qr(np.column_stack([fields.real, fields.imag]))[0]
            Kr, Mr = V.T @ (K @ V), V.T @ (M @ V)
        mu, phi = sla.eigh(0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T))
        self.W = V @ phi  # (n, m), K- and M-orthogonal
        self.mu = mu
        lam = (w**2 - 1j * w * self.a) / (1.0 + 1j * w * self.b)
        self.g = 1.0 / ((1.0 + 1j * w * self.b)[:, None] * (mu[None, :] - lam[:, None]))  # (p, m)
        self.left = np.asarray((L.T @ self.W))  # (n_s, m)
        self.right = self.W.T @ loads[:, 0]  # (m,)
        self.Z = np.einsum("sm,pm,m->ps", self.left, self.g, self.right)
        # Per frequency and sensor: u = left g (dual), v = g right (primal), in modal coordinates.
        self._u = self.left[None, :, :] * self.g[:, None, :]  # (p, n_s, m)
        self._v = self.g * self.right[None, :]  # (p, m)

    @property
    def amplitude(self) -> np.ndarray:
        return np.abs(self.Z) * (1.0 + self.gain)[None, :]

    def project(self, A) -> np.ndarray:
        """``W^T A W`` for a sparse (n, n) change, shape (m, m); only A's non-empty rows are read."""
        return project_rows(A, self.W)

    def _bilinear(self, A: np.ndarray) -> np.ndarray:
        """``u_ps^T A v_p`` for every frequency and sensor, shape (p, n_s)."""
        # A is real: two real products, not one complex one (OpenBLAS's zgemm on these small
        # matrices spins its threads: 46 ms against 0.2 ms on 2 busy cores, measured).
        At = A.T
        Av = self._v.real @ At + 1j * (self._v.imag @ At) if np.isrealobj(A) else self._v @ At  # (p, m)
        return modal_sum(self.left, self.g, Av)

    def dlog(self, dK=None, dM=None, da: float = 0.0, db: float = 0.0, dgain=None) -> np.ndarray:
        """``d ln(|Z_s| (1 + g_s))`` per unit of the change, shape (p, n_s).

        ``dK``, ``dM`` sparse (n, n) or already projected (m, m) arrays; ``da``, ``db``
        changes of the Rayleigh coefficients; ``dgain`` (n_s,) a change of the gains.
        """
        w = self.omegas
        dZ = np.zeros((w.size, self.left.shape[0]), dtype=complex)
        if dK is not None:
            Ak = dK if isinstance(dK, np.ndarray) else self.project(dK)
            dZ += (1.0 + 1j * w * self.b)[:, None] * self._bilinear(Ak)
        if dM is not None:
            Am = dM if isinstance(dM, np.ndarray) else self.project(dM)
            dZ += (-(w**2) + 1j * w * self.a)[:, None] * self._bilinear(Am)
        if da or db:  # W^T M W = I, W^T K W = diag(mu)
            diag = (1j * w)[:, None] * (da + db * self.mu[None, :])
            dZ += modal_sum(self.left, self.g, diag * self._v)
        out = np.real(-dZ / self.Z)
        if dgain is not None:  # ln(1 + g): d/dg = 1 / (1 + g)
            out = out + (np.asarray(dgain, float) / (1.0 + self.gain))[None, :]
        return out

    def diagonal_dlog(self, matrix: str, rows: np.ndarray) -> np.ndarray:
        """``d ln|Z|`` for many unit diagonal changes at once, shape (L, p, n_s).

        Change ``l`` adds 1 to the diagonal of K (``matrix="stiffness"``) or M
        (``"mass"``) at the free DOFs ``rows[l]`` (shape (L, k); negative entries
        are skipped): a point mass or a grounded spring at every node in one
        product, ``dZ_s = -c(w) sum_r (u_s . W_r)(W_r . v)``.

        The DOFs' modal rows meet ``u`` and ``v`` in real matrix products (``W`` is real: two real products
        take half the work of one complex one), :data:`DIAGONAL_CHUNK` locations at a time (a (chunk, k, p,
        n_s) complex block, not one for every DOF of the mesh: 2.2 GB at 25,000 DOFs and 700 lines), the blocks
        on the threads of :func:`fe_core.threads.thread_map`.
        """
        rows = np.atleast_2d(np.asarray(rows, dtype=np.int64))
        w = self.omegas
        c = (1.0 + 1j * w * self.b) if matrix == "stiffness" else (-(w**2) + 1j * w * self.a)
        p, n_s = self.Z.shape
        m = self.W.shape[1]
        u = self._u.reshape(p * n_s, m)
        u_re, u_im = np.ascontiguousarray(u.real.T), np.ascontiguousarray(u.imag.T)  # (m, p n_s)
        v_re, v_im = np.ascontiguousarray(self._v.real.T), np.ascontiguousarray(self._v.imag.T)  # (m, p)
        scale = -c[:, None] / self.Z  # (p, n_s)
        out = np.zeros((rows.shape[0], p, n_s))
        if rows.shape[1] == 0:  # changes at no free DOF (an effect whose nodes the model does not hold): none
            return out

        def chunk(start):  # independent blocks: on the threads (fe_core.threads)
            block = rows[start:start + DIAGONAL_CHUNK]
            used, where = np.unique(block, return_inverse=True)
            Wu = self.W[np.maximum(used, 0)]  # (nu, m); the row of index -1 (if any) is zeroed
            Wu[used < 0] = 0.0
            a = (Wu @ u_re + 1j * (Wu @ u_im)).reshape(-1, p, n_s)  # u_s . W_r
            b = Wu @ v_re + 1j * (Wu @ v_im)  # (nu, p): W_r . v
            unit = a * b[:, :, None]  # (nu, p, n_s)
            summed = unit[where.reshape(block.shape)].sum(axis=1) if block.shape[1] > 1 else unit[where.ravel()]
            out[start:start + block.shape[0]] = np.real(summed * scale[None])

        thread_map(chunk, range(0, rows.shape[0], DIAGONAL_CHUNK))
        return out
