"""The local flexibility a reduced space lacks at a candidate's place, restored by static vectors (mode acceleration).

Why: the space of :class:`.reduced.ReducedModel` holds the responses to the load and to the sensor loads, so the
receptances from the load and from the sensors to any node are in it (reciprocity), but a node's drive-point
receptance is not: a point load on a solid mesh moves its node mostly through the many high modes near it, which
no space of a few hundred global vectors holds. A point mass or a spring at that node feels exactly this local
flexibility. On the ribbed tet10 panel of the eleventh held-out set (hk07: a 0.29 kg mass) the true node's joint
fit ended at a sum of squares of 259 in the space without it and at 15.1 with the node's three static vectors
joined, the full FE model's value; the neighbouring node the closure had found went from 71.9 to 52.3 (the full
model's 52.3), so the reduced search ranked the wrong node first.

Two uses, both with ``X = K0^-1 E`` (``E`` the unit vectors of the candidate's DOFs, ``K0`` the stiffness at the
reduced model's point):

* :meth:`LocalFlexibility.residual`: the flexibility the space misses at the candidate's rows,
  ``R = E^T X - U^T K_r^-1 U`` (q x q), added to the Woodbury scan's ``G(w) = U^T D0(w)^-1 U`` as ``R / (1 + j w b)``
  (the missing modes are far above the band: their dynamic flexibility is the static one);
* :meth:`LocalFlexibility.border`: the space with ``X`` joined (M-orthonormalised against it), for a candidate's
  joint fit: exact for that candidate wherever its response is the point's response plus its local deformation.
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.linalg as sla

__all__ = ["LocalFlexibility", "BLOCK"]

#: Right-hand sides per block solve (at 500k DOFs a block of the solutions is 0.4 GB).
BLOCK = 96


class LocalFlexibility:
    """Static solves at a reduced model's point (``K0`` with its applied effects), for its scan and its joint fits.

    Parameters
    ----------
    rm : ReducedModel
        Its ``model``, ``alpha0``, ``applied``, basis ``W`` (``W^T K0 W = diag(mu)``, ``W^T M W = I``) and ``mu``.
    shift : float, optional
        Solve with ``K0 + shift M`` (the flexibility at ``w^2 = -shift``); by default 0, or the band's lowest
        ``w^2`` where ``K0`` is singular (a free structure).
    """

    def __init__(self, rm, shift: float | None = None):
        from ...solvers.frf import spd_solver
        from ..effects import extended_matrices

        self.rm = rm
        self.K, self.M, _, _ = extended_matrices(rm.model, rm.alpha0, rm.applied)
        self.shift = 0.0 if shift is None else float(shift)
        self.solve = spd_solver(self.K) if self.shift == 0.0 else None
        if self.solve is None:  # a free structure (rigid-body modes): K + s M with s the band's lowest w^2
            if shift is None:
                self.shift = float(np.min(rm.omegas)) ** 2
            self.solve = spd_solver(self.K + self.shift * self.M)
            if self.solve is None:
                raise np.linalg.LinAlgError(f"K + {self.shift:.3g} M at the reduced model's point is not "
                                            "positive-definite (a negative stiffness?)")
        self._flex: dict = {}         # (row, row) -> the (shifted) static flexibility between them
        self._lock = threading.Lock()   # one factor, solved from the search's threads one block at a time

    def _solve(self, E: np.ndarray) -> np.ndarray:
        with self._lock:
            return self.solve(E)

    def residual(self, rows: np.ndarray) -> np.ndarray:
        """``R`` (L, q, q) of candidates' rows (L, q) (free-DOF indices, -1 padded: zero rows and columns there).
        The static flexibility is cached by pairs of rows: a spring at a node a point mass was scanned at costs no
        solve."""
        rows = np.atleast_2d(np.asarray(rows, np.int64))
        L, q = rows.shape
        flex = self._flex
        todo = [k for k in range(L) if any((a, b) not in flex for a in rows[k] if a >= 0 for b in rows[k] if b >= 0)]
        n = self.K.shape[0]
        per = max(1, BLOCK // q)
        for j in range(0, len(todo), per):
            part = todo[j:j + per]
            cols = sorted({int(r) for k in part for r in rows[k] if r >= 0})
            E = np.zeros((n, len(cols)))
            E[cols, np.arange(len(cols))] = 1.0
            X = self._solve(E)
            del E
            at = {c: m for m, c in enumerate(cols)}
            for k in part:
                for a in rows[k][rows[k] >= 0]:
                    for b in rows[k][rows[k] >= 0]:
                        flex[(int(a), int(b))] = float(X[a, at[int(b)]])
        out = np.zeros((L, q, q))
        W, mu = self.rm.W, self.rm.mu + self.shift
        for k in range(L):
            valid = np.flatnonzero(rows[k] >= 0)
            r = rows[k][valid]
            full = np.array([[flex[(int(a), int(b))] for b in r] for a in r])
            Wr = W[r]
            out[k][np.ix_(valid, valid)] = _sym(full - (Wr / mu[None, :]) @ Wr.T)
        return out

    def border(self, rows) -> dict:
        """The pieces of the space joined by the static vectors of ``rows`` (free-DOF indices): ``V`` (n, q')
        M-orthonormal and M-orthogonal to ``W``, the bordered ``k0`` (the projected ``K0``), the segments'
        projections, ``left`` and ``right``; ``V`` is empty where the vectors lie in the space already."""
        rm = self.rm
        rows = np.unique(np.asarray(rows, np.int64).ravel())
        rows = rows[rows >= 0]
        E = np.zeros((self.K.shape[0], rows.size))
        E[rows, np.arange(rows.size)] = 1.0
        V = self._solve(E)
        del E
        for _ in range(2):  # twice: one Gram-Schmidt pass against W loses what cancellation leaves
            V = V - rm.W @ (rm.W.T @ (self.M @ V))
        gram = _sym(V.T @ (self.M @ V))
        lam, vec = sla.eigh(gram)
        keep = lam > 1e-12 * max(lam.max(initial=0.0), 1e-300) if lam.size else lam > 0
        V = V @ (vec[:, keep] / np.sqrt(lam[keep])[None, :])
        KV = self.K @ V
        k0 = np.block([[np.diag(rm.mu), rm.W.T @ KV], [KV.T @ rm.W, V.T @ KV]])
        segments = []
        from ..effects.extended import segment_stiffness

        for i, S in enumerate(rm.segments):
            SV = segment_stiffness(rm.model, i) @ V
            segments.append(_sym(np.block([[S, rm.W.T @ SV], [SV.T @ rm.W, V.T @ SV]])))
        left = np.hstack([rm.left, np.asarray(rm.model.outputs.T @ V)])
        right = np.concatenate([rm.right, V.T @ rm.model.combined_load()])
        return {"V": V, "k0": _sym(k0), "segments": segments, "left": left, "right": right}


def _sym(A) -> np.ndarray:
    A = np.asarray(A, float)
    return 0.5 * (A + A.T)
