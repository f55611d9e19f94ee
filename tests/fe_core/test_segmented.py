"""Segment matrices stored on their own entries (fe_core.assembly.SegmentedMatrix, large models) against the
explicit sums of the segment matrices (the reference), and against the dense rows small models keep."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import fe_core.assembly as assembly
from fe_core.assembly import SegmentedMatrix


@pytest.fixture
def parts():
    """Three random symmetric 'segments' overlapping on some entries, one with an explicit zero, and a remainder
    whose entry cancels another's in the sum."""
    rng = np.random.default_rng(7)
    n = 40
    mats = []
    for k in range(3):
        A = sp.random(n, n, density=0.08, random_state=rng, format="csr")
        A = sp.csr_matrix(A + A.T + sp.eye(n))
        mats.append(A)
    mats[1] = mats[1].tolil()
    mats[1][3, 3] = 0.0  # an explicit zero inside a segment
    mats[1] = sp.csr_matrix(mats[1])
    rest = sp.csr_matrix(([-mats[0][0, 0]], ([0], [0])), shape=(n, n))
    return mats, rest


@pytest.mark.parametrize("compact_rows", [0, 10**9])
def test_combine_segment_own_equal_the_explicit_sums(parts, monkeypatch, compact_rows):
    mats, rest = parts
    monkeypatch.setattr(assembly, "COMPACT_ROWS", compact_rows)
    S = SegmentedMatrix.from_matrices(mats, rest)
    w = np.array([1.3, 0.4, 2.0])
    explicit = sum(wi * A for wi, A in zip(w, mats)) + rest
    K = S.combine(w)
    assert abs(K - explicit).max() <= 1e-14 * abs(explicit).max()
    assert K.nnz == S.pattern.nnz  # every slot of the union kept
    for i, A in enumerate(mats):
        assert abs(S.segment(i) - A).max() == 0.0
        own = S.own(i)
        assert abs(own - A).max() == 0.0 and own.nnz == sp.csr_matrix(A).count_nonzero()
    assert abs(S.remainder() - rest).max() == 0.0
    assert np.array_equal(S.data[1], S.segment(1).toarray().ravel()[np.ravel_multi_index(
        (np.repeat(np.arange(40), np.diff(S.pattern.indptr)), S.pattern.indices), (40, 40))])


def test_large_storage_holds_one_matrix_not_one_per_segment(parts, monkeypatch):
    mats, rest = parts
    monkeypatch.setattr(assembly, "COMPACT_ROWS", 0)
    S = SegmentedMatrix.from_matrices(mats, rest)
    entries = sum(A.count_nonzero() for A in mats) + 1
    assert S.values.size == entries and S.slots.dtype == np.int32
    assert S.pattern.data.strides == (0,)  # the pattern's values are not stored
    dense = S.n_parts * S.pattern.nnz * 8
    assert S.nbytes < 0.7 * dense
