"""The upper triangle and the half-bandwidth of a large sparse matrix without its COO copy.

``scipy.sparse.triu(A)`` goes through COO: the row and column of every stored entry and a copy of its value
(16 bytes an entry on top of the CSR arrays; 0.6 GB for the stiffness of the 500k-DOF panel, 36.6 M entries) and
masks of the whole length, so that one call briefly held about a gigabyte more than the matrix, at every FE run and
in the global basis's start (docs/results/scaling.md). Here the rows are expanded a block at a time: a flag per
entry and the triangle's own arrays are all that is held.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["upper_triangle", "half_bandwidth"]

#: Entries per block of the row expansion (8 MB of row indices).
BLOCK_ENTRIES = 1 << 20


def _csr(A) -> sp.csr_matrix:
    """A in canonical CSR (duplicates summed, as COO's conversion would)."""
    A = A if sp.isspmatrix_csr(A) else sp.csr_matrix(A)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


def _blocks(indptr: np.ndarray):
    """Row ranges ``(r0, r1)`` of about :data:`BLOCK_ENTRIES` entries each."""
    n = indptr.size - 1
    r0 = 0
    while r0 < n:
        r1 = int(np.searchsorted(indptr, int(indptr[r0]) + BLOCK_ENTRIES, side="right")) - 1
        r1 = min(n, max(r1, r0 + 1))
        yield r0, r1
        r0 = r1


def _row_minus_column(A: sp.csr_matrix, r0: int, r1: int) -> np.ndarray:
    """``column - row`` of the entries stored in rows ``r0:r1``."""
    a, b = A.indptr[r0], A.indptr[r1]
    rows = np.repeat(np.arange(r0, r1, dtype=np.int64), np.diff(A.indptr[r0:r1 + 1]))
    return A.indices[a:b].astype(np.int64) - rows


def upper_triangle(A) -> sp.csr_matrix:
    """The upper triangle of A (the diagonal included) as a CSR matrix of floats: the same matrix as
    ``scipy.sparse.triu(A, format="csr").astype(float)``; each row's entries in A's order when A is canonical
    (sorted, no duplicates: an assembled K), else as :meth:`~scipy.sparse.csr_matrix.sum_duplicates` leaves them."""
    A = _csr(A)
    n = A.shape[0]
    keep = np.empty(A.nnz, dtype=bool)
    counts = np.zeros(n, dtype=np.int64)
    for r0, r1 in _blocks(A.indptr):
        a, b = A.indptr[r0], A.indptr[r1]
        keep[a:b] = _row_minus_column(A, r0, r1) >= 0
        counts[r0:r1] = _row_counts(keep[a:b], A.indptr[r0:r1 + 1] - a)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    index_type = A.indices.dtype if indptr[-1] <= np.iinfo(np.int32).max else np.int64
    data = np.asarray(A.data[keep], dtype=float)
    indices = A.indices[keep]
    del keep
    return sp.csr_matrix((data, indices, indptr.astype(index_type)), shape=A.shape)


def _row_counts(flags: np.ndarray, local_indptr: np.ndarray) -> np.ndarray:
    """The number of set flags in each row (rows given by their offsets in ``flags``)."""
    total = np.concatenate([[0], np.cumsum(flags, dtype=np.int64)])
    return total[local_indptr[1:]] - total[local_indptr[:-1]]


def half_bandwidth(A) -> int:
    """The largest ``column - row`` of A's stored entries (0 for a diagonal or lower-triangular matrix)."""
    A = _csr(A)
    width = 0
    for r0, r1 in _blocks(A.indptr):
        if A.indptr[r1] > A.indptr[r0]:
            width = max(width, int(_row_minus_column(A, r0, r1).max()))
    return width
