"""Sparse assembly of element matrices, DOF bookkeeping and parametrised sums.

Each segment's matrices are assembled once. Because updating only rescales
them, all segment matrices are stored on one common sparsity pattern, so that
``K(alpha) = sum_i (1 + alpha_i) K_i`` is a single dense product of a
(n_segments,) weight vector with a (n_segments, nnz) data array.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

__all__ = ["DOFS_PER_NODE", "cell_dofs", "assemble", "free_dof_map", "SegmentedMatrix"]

DOFS_PER_NODE = 3


def cell_dofs(cells: np.ndarray) -> np.ndarray:
    """Global DOF numbers of each cell, node-major ``[u_x, u_y, u_z]``.

    Parameters
    ----------
    cells : ndarray, shape (n_cells, 8), int

    Returns
    -------
    ndarray, shape (n_cells, 24), int
    """
    return (DOFS_PER_NODE * cells[:, :, None] + np.arange(DOFS_PER_NODE)).reshape(cells.shape[0], -1)


def assemble(element_matrices: np.ndarray, dofs: np.ndarray, n_dofs: int) -> sp.csr_matrix:
    """Assemble element matrices into a global sparse matrix.

    Parameters
    ----------
    element_matrices : ndarray, shape (n_cells, d, d)
    dofs : ndarray, shape (n_cells, d), int
    n_dofs : int

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_dofs, n_dofs)
    """
    d = dofs.shape[1]
    rows = np.repeat(dofs, d, axis=1).ravel()
    cols = np.tile(dofs, (1, d)).ravel()
    A = sp.coo_matrix((element_matrices.ravel(), (rows, cols)), shape=(n_dofs, n_dofs)).tocsr()
    A.sum_duplicates()
    return A


def free_dof_map(n_dofs: int, fixed: np.ndarray) -> np.ndarray:
    """Free DOF numbers, ascending, given the fixed ones.

    Returns
    -------
    ndarray, shape (n_free,), int
    """
    mask = np.ones(n_dofs, dtype=bool)
    mask[np.asarray(fixed, dtype=int)] = False
    return np.flatnonzero(mask)


@dataclass
class SegmentedMatrix:
    """A sum of segment matrices on one sparsity pattern.

    Attributes
    ----------
    pattern : scipy.sparse.csr_matrix, shape (n, n)
        The union pattern (its data are the unscaled sum, remainder included).
    data : ndarray, shape (n_segments, nnz)
        Each segment's entries on ``pattern``.
    fixed : ndarray, shape (nnz,), or None
        The fixed remainder's entries on ``pattern`` (cells in no segment), added
        unscaled by :meth:`combine`; None when every cell belongs to a segment.
    """

    pattern: sp.csr_matrix
    data: np.ndarray
    fixed: np.ndarray | None = None

    @classmethod
    def from_matrices(cls, matrices: Sequence[sp.spmatrix], remainder: sp.spmatrix | None = None
                      ) -> "SegmentedMatrix":
        """Segment matrices (and an optional fixed remainder) on their union pattern."""
        mats = [sp.csr_matrix(m, dtype=float) for m in matrices]
        if remainder is not None:
            mats.append(sp.csr_matrix(remainder, dtype=float))
        for m in mats:
            m.sum_duplicates()
            m.sort_indices()
        # The union pattern is built from ones, so entries that cancel in the
        # sum (scipy drops exact zeros in sparse additions) keep their slot.
        coo = [m.tocoo() for m in mats]
        rows = np.concatenate([c.row for c in coo])
        cols = np.concatenate([c.col for c in coo])
        total = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=mats[0].shape)
        total.sum_duplicates()
        total.sort_indices()
        n = total.shape[1]
        union_keys = _keys(total, n)
        data = np.zeros((len(mats), total.nnz))
        for i, m in enumerate(mats):
            # Exact alignment: each entry goes to its (row, col) slot in the union.
            data[i, np.searchsorted(union_keys, _keys(m, n))] = m.data
        total.data = data.sum(axis=0)
        if remainder is not None:
            return cls(pattern=total, data=data[:-1], fixed=data[-1])
        return cls(pattern=total, data=data)

    @property
    def n_segments(self) -> int:
        return self.data.shape[0]

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    def segment(self, i: int) -> sp.csr_matrix:
        """Segment ``i``'s matrix on the common pattern."""
        return self._with_data(self.data[i].copy())

    def remainder(self) -> sp.csr_matrix:
        """The fixed remainder on the common pattern (zero when there is none)."""
        return self._with_data(np.zeros(self.pattern.nnz) if self.fixed is None else self.fixed.copy())

    def combine(self, weights: np.ndarray) -> sp.csr_matrix:
        """``sum_i weights[i] * segment_i`` as a CSR matrix.

        Parameters
        ----------
        weights : ndarray, shape (n_segments,)
        """
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (self.n_segments,):
            raise ValueError(f"expected {self.n_segments} weights, got shape {weights.shape}")
        combined = weights @ self.data
        return self._with_data(combined if self.fixed is None else combined + self.fixed)

    def _with_data(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix(
            (data, self.pattern.indices, self.pattern.indptr), shape=self.pattern.shape, copy=False
        )


def _keys(A: sp.csr_matrix, n_cols: int) -> np.ndarray:
    """Row-major linear index of each stored entry of a CSR matrix with sorted indices."""
    rows = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr))
    return rows * n_cols + A.indices.astype(np.int64)
