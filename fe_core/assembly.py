"""Sparse assembly of element matrices, DOF bookkeeping and parametrised sums.

Each segment's matrices are assembled once. Because updating only rescales
them, all segment matrices share one sparsity pattern (their union), and each
segment is stored on its own entries only (their slots in the union and their
values): ``K(alpha) = sum_i (1 + alpha_i) K_i`` is one scatter-add per segment
into the union's data array, and the memory is about one matrix's, whatever the
number of segments (:class:`SegmentedMatrix`). :func:`assemble_free` assembles
element matrices directly on the free DOFs, a chunk of cells at a time, so a
large mesh never holds all its element matrices at once.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

__all__ = ["DOFS_PER_NODE", "cell_dofs", "assemble", "assemble_free", "free_dof_map", "SegmentedMatrix"]

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


def assemble_free(blocks, n_dofs: int, free: np.ndarray) -> sp.csr_matrix:
    """Assemble element matrices on the free DOFs, a block of cells at a time.

    Parameters
    ----------
    blocks : iterable of (ndarray (c, d, d), ndarray (c, d) of int)
        Element matrices of ``c`` cells and their global DOF numbers (:func:`cell_dofs`).
    n_dofs : int
        Global DOFs.
    free : ndarray of int
        The free DOFs, ascending (:func:`free_dof_map`): the rows and columns kept.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (free.size, free.size)
        Each block is assembled by :func:`assemble` and restricted to the free DOFs, then the blocks are
        summed: the memory is one block's triplets plus the partial sums, not every cell's ``d x d`` triplets at
        once. One block gives exactly ``assemble(...)[free][:, free]`` (explicit zeros kept, entries summed in
        the same order); several differ from it in the last bits of entries that several blocks share.
    """
    total = None
    for Ke, dofs in blocks:
        A = assemble(np.asarray(Ke, dtype=float), dofs, n_dofs)[free][:, free]
        total = A if total is None else _add_keeping_zeros(total, A)
    return sp.csr_matrix((free.size, free.size)) if total is None else total


def _add_keeping_zeros(A: sp.csr_matrix, B: sp.csr_matrix) -> sp.csr_matrix:
    """``A + B`` whose pattern is the union of theirs (scipy's sum drops entries that cancel)."""
    A, B = A.tocoo(), B.tocoo()
    S = sp.coo_matrix((np.concatenate([A.data, B.data]), (np.concatenate([A.row, B.row]),
                                                          np.concatenate([A.col, B.col]))), shape=A.shape).tocsr()
    S.sum_duplicates()
    return S


def free_dof_map(n_dofs: int, fixed: np.ndarray) -> np.ndarray:
    """Free DOF numbers, ascending, given the fixed ones.

    Returns
    -------
    ndarray, shape (n_free,), int
    """
    mask = np.ones(n_dofs, dtype=bool)
    mask[np.asarray(fixed, dtype=int)] = False
    return np.flatnonzero(mask)


#: Matrices with at least this many rows keep only each segment's own entries (:class:`SegmentedMatrix`); smaller
#: ones keep the dense rows as well, and combine them as they always did.
COMPACT_ROWS = 50_000


class SegmentedMatrix:
    """A sum of segment matrices on one sparsity pattern, each segment stored on its own entries.

    ``K(alpha) = fixed + sum_i (1 + alpha_i) K_i`` is assembled by :meth:`combine` into the union pattern
    of all segments: one scatter-add per segment. Each segment keeps only its own entries (their slots in
    the union pattern and their values), so the memory is that of one matrix plus one index per entry,
    not ``n_segments`` copies of the union (a 6-segment tet10 model of 464k DOFs: 0.45 GB for K instead
    of 2 GB). Below :data:`COMPACT_ROWS` rows the dense rows are kept too and :meth:`combine` is their
    product with the weights, as it always was: a scatter-add sums in another order, and small models keep
    their results to the last bit.

    Parameters
    ----------
    pattern : scipy.sparse.csr_matrix, shape (n, n)
        The union pattern (sorted indices); its data are the unscaled sum, remainder included (a matrix of
        :data:`COMPACT_ROWS` rows or more keeps only the index arrays: :attr:`pattern`'s values are then ones).
    data : ndarray, shape (n_segments, nnz), optional
        Each segment's entries on ``pattern`` (dense rows; stored compactly: the non-zero entries).
    fixed : ndarray, shape (nnz,), or None
        The fixed remainder's entries on ``pattern`` (cells in no segment), added unscaled by :meth:`combine`.

    Attributes
    ----------
    slots : ndarray, shape (total,), int32
        Position in ``pattern.data`` of each stored entry, part after part (the segments, then the
        remainder when there is one).
    values : ndarray, shape (total,)
        The stored entries' values.
    offsets : ndarray, shape (n_parts + 1,), int64
        Part ``k``'s entries are ``slots[offsets[k]:offsets[k + 1]]``.
    n_segments : int
    has_fixed : bool
    """

    def __init__(self, pattern: sp.csr_matrix, data: np.ndarray | None = None, fixed: np.ndarray | None = None):
        rows = [] if data is None else list(np.atleast_2d(np.asarray(data, dtype=float)))
        self.n_segments = len(rows)
        self.has_fixed = fixed is not None
        if fixed is not None:
            rows.append(np.asarray(fixed, dtype=float))
        parts = [(np.flatnonzero(r).astype(np.int32 if r.size < 2**31 else np.int64), r[r != 0]) for r in rows]
        self._store(pattern, parts)

    def _store(self, pattern, parts) -> None:
        if pattern.shape[0] >= COMPACT_ROWS:  # the pattern's index arrays only: its values are never read
            self._pattern, self._indices, self._indptr = None, pattern.indices, pattern.indptr
            self._shape = pattern.shape
        else:
            self._pattern = pattern
        self.offsets = np.concatenate([[0], np.cumsum([s.size for s, _ in parts])]).astype(np.int64)
        index = np.int32 if pattern.nnz < 2**31 else np.int64
        self.slots = np.concatenate([s for s, _ in parts]).astype(index, copy=False) if parts else np.zeros(0, index)
        self.values = np.concatenate([v for _, v in parts]) if parts else np.zeros(0)
        # A small matrix also keeps the dense rows: its K(alpha) is then the product it always was (BLAS's
        # summation order, bit for bit); a large one only its own entries (the memory of one matrix).
        self._dense = self.data if pattern.shape[0] < COMPACT_ROWS else None
        self._dense_fixed = self.fixed if self._dense is not None else None

    @classmethod
    def from_parts(cls, pattern: sp.csr_matrix, parts: Sequence[tuple[np.ndarray, np.ndarray]],
                   n_segments: int) -> "SegmentedMatrix":
        """From each part's ``(slots, values)`` on ``pattern``: the segments, then the remainder if
        ``len(parts) > n_segments``."""
        obj = cls.__new__(cls)
        obj.n_segments = int(n_segments)
        obj.has_fixed = len(parts) > n_segments
        obj._store(pattern, list(parts))
        return obj

    @classmethod
    def from_matrices(cls, matrices: Sequence[sp.spmatrix], remainder: sp.spmatrix | None = None
                      ) -> "SegmentedMatrix":
        """Segment matrices (and an optional fixed remainder) on their union pattern.

        The union is built from each matrix's pattern (not its values), so entries that cancel in the sum
        keep their slot; each matrix is then stored on its own entries (explicit zeros dropped).
        """
        mats = [sp.csr_matrix(m, dtype=float) for m in matrices]
        if remainder is not None:
            mats.append(sp.csr_matrix(remainder, dtype=float))
        total = None
        for m in mats:
            m.sum_duplicates()
            m.sort_indices()
            ones = sp.csr_matrix((np.ones(m.nnz), m.indices, m.indptr), shape=m.shape)
            total = ones if total is None else total + ones  # positive: no entry cancels
        total.sum_duplicates()
        total.sort_indices()
        n = total.shape[1]
        union_keys = _keys(total, n)
        parts = []
        for m in mats:
            keep = m.data != 0
            slots = np.searchsorted(union_keys, _keys(m, n)[keep])  # exact: every key is in the union
            parts.append((slots, m.data[keep]))
        del union_keys
        total.data = np.zeros(total.nnz)
        for slots, values in parts:  # the unscaled sum, part after part
            total.data[slots] += values
        return cls.from_parts(total, parts, len(matrices))

    @property
    def pattern(self) -> sp.csr_matrix:
        """The union pattern (sorted indices). Its values: the unscaled sum for a small matrix; ones (a
        zero-stride view, no memory) for a large one, which keeps only the index arrays."""
        if self._pattern is not None:
            return self._pattern
        ones = np.broadcast_to(np.float64(1.0), self._indices.shape)
        return sp.csr_matrix((ones, self._indices, self._indptr), shape=self._shape, copy=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self._shape if self._pattern is None else self._pattern.shape

    @property
    def n_parts(self) -> int:
        return self.n_segments + int(self.has_fixed)

    def part(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(slots, values)`` of part ``k`` (segment ``k``, or the remainder for ``k = n_segments``)."""
        a, b = self.offsets[k], self.offsets[k + 1]
        return self.slots[a:b], self.values[a:b]

    @property
    def data(self) -> np.ndarray:
        """Each segment's entries on ``pattern``, shape (n_segments, nnz) (dense: built on request)."""
        if getattr(self, "_dense", None) is not None:
            return self._dense
        out = np.zeros((self.n_segments, self.pattern.nnz))
        for i in range(self.n_segments):
            slots, values = self.part(i)
            out[i, slots] = values
        return out

    @property
    def fixed(self) -> np.ndarray | None:
        """The remainder's entries on ``pattern``, shape (nnz,), or None."""
        if not self.has_fixed:
            return None
        if getattr(self, "_dense_fixed", None) is not None:
            return self._dense_fixed
        out = np.zeros(self.pattern.nnz)
        slots, values = self.part(self.n_segments)
        out[slots] = values
        return out

    def segment(self, i: int) -> sp.csr_matrix:
        """Segment ``i``'s matrix on the common pattern (zeros outside the segment)."""
        out = np.zeros(self.pattern.nnz)
        slots, values = self.part(i)
        out[slots] = values
        return self._with_data(out)

    def own(self, i: int) -> sp.csr_matrix:
        """Segment ``i``'s matrix on its own entries (no explicit zeros): what a product with it costs.

        Its values are a copy, in the process's own memory. A view of a cached model's mapped pages saves 0.29 GB
        at 500k DOFs, but the one 500k update measured with it took 837 s against 603-687 s without
        (docs/results/scaling.md); the machines here page out file pages cold for about a second (DAMON, no swap),
        which the Jacobian's products, seconds apart, would read back each time."""
        slots, values = self.part(i)
        rows = np.searchsorted(self.pattern.indptr, slots, side="right") - 1
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=self.shape[0]))])
        return sp.csr_matrix((values.copy(), self.pattern.indices[slots], indptr), shape=self.shape)

    def remainder(self) -> sp.csr_matrix:
        """The fixed remainder on the common pattern (zero when there is none)."""
        fixed = self.fixed
        return self._with_data(np.zeros(self.pattern.nnz) if fixed is None else fixed)

    def combine(self, weights: np.ndarray) -> sp.csr_matrix:
        """``sum_i weights[i] * segment_i`` (plus the remainder) as a CSR matrix on the common pattern.

        Parameters
        ----------
        weights : ndarray, shape (n_segments,)
        """
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (self.n_segments,):
            raise ValueError(f"expected {self.n_segments} weights, got shape {weights.shape}")
        if self._dense is not None:
            combined = weights @ self._dense
            return self._with_data(combined if self._dense_fixed is None else combined + self._dense_fixed)
        out = np.zeros(self.pattern.nnz)
        for i, w in enumerate(weights):
            slots, values = self.part(i)
            out[slots] += w * values  # a segment's slots are distinct: no entry is lost
        if self.has_fixed:
            slots, values = self.part(self.n_segments)
            out[slots] += values
        return self._with_data(out)

    @property
    def nbytes(self) -> int:
        """Bytes held (the pattern's arrays, slots, values, and the dense rows of a small matrix)."""
        p = self.pattern
        held = p.indices.nbytes + p.indptr.nbytes + self.slots.nbytes + self.values.nbytes
        if self._pattern is not None:
            held += p.data.nbytes
        if self._dense is not None:
            held += self._dense.nbytes
        return int(held)

    def _with_data(self, data: np.ndarray) -> sp.csr_matrix:
        indices, indptr = ((self._indices, self._indptr) if self._pattern is None
                           else (self._pattern.indices, self._pattern.indptr))
        return sp.csr_matrix((data, indices, indptr), shape=self.shape, copy=False)


def _keys(A: sp.csr_matrix, n_cols: int) -> np.ndarray:
    """Row-major linear index of each stored entry of a CSR matrix with sorted indices."""
    rows = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr))
    return rows * n_cols + A.indices.astype(np.int64)
