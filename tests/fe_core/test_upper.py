"""The upper triangle and half-bandwidth without a COO copy, against scipy.sparse.triu and the dense matrix."""

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.solvers import upper


def _random(n, density, seed, empty_rows=()):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, random_state=rng, format="csr")
    A = (A + A.T + sp.eye(n)).tolil()
    for r in empty_rows:
        A[r, :] = 0
    A = A.tocsr()
    A.eliminate_zeros()
    return A


@pytest.mark.parametrize("block", [1 << 20, 7, 1])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_upper_triangle_is_scipys_triu(monkeypatch, block, seed):
    monkeypatch.setattr(upper, "BLOCK_ENTRIES", block)
    A = _random(60, 0.1, seed, empty_rows=(0, 17, 59))
    A.data[::5] = 0.0  # explicit zeros are kept, as triu keeps them
    U = upper.upper_triangle(A)
    ref = sp.triu(A, format="csr").astype(float)
    ref.sort_indices()
    U.sort_indices()
    np.testing.assert_array_equal(U.indptr, ref.indptr)
    np.testing.assert_array_equal(U.indices, ref.indices)
    np.testing.assert_array_equal(U.data, ref.data)
    np.testing.assert_array_equal(U.toarray(), np.triu(A.toarray()))
    assert U.dtype == np.float64


def test_unsorted_duplicated_and_integer_input():
    A = sp.csr_matrix((np.array([1, 2, 3, 4, 5, 6]), np.array([2, 0, 1, 1, 0, 2]), np.array([0, 2, 4, 6])),
                      shape=(3, 3))  # row 1 holds column 1 twice; row 0 unsorted; integer values
    U = upper.upper_triangle(A)
    np.testing.assert_array_equal(U.toarray(), np.triu(A.toarray()).astype(float))
    assert U.dtype == np.float64
    assert upper.half_bandwidth(A) == 2


@pytest.mark.parametrize("block", [1 << 20, 3])
def test_half_bandwidth(monkeypatch, block):
    monkeypatch.setattr(upper, "BLOCK_ENTRIES", block)
    A = sp.diags([np.ones(10), np.ones(9), np.ones(8)], [0, -1, 2], shape=(10, 10), format="csr")
    assert upper.half_bandwidth(A) == 2
    assert upper.half_bandwidth(sp.tril(A, format="csr")) == 0
    assert upper.half_bandwidth(sp.csr_matrix((5, 5))) == 0
    B = _random(40, 0.2, 3)
    coo = B.tocoo()
    assert upper.half_bandwidth(B) == int(np.max(coo.col - coo.row))


def test_blocks_near_the_int32_limit_do_not_overflow(monkeypatch):
    """Row blocks of an int32 indptr whose offsets are close to 2**31 (a matrix of two billion entries): the block
    bound is computed in Python integers, without numpy's overflow warning (an error under the tests' settings)."""
    monkeypatch.setattr(upper, "BLOCK_ENTRIES", 1 << 20)
    top = np.iinfo(np.int32).max - 10
    indptr = np.array([0, top - 100, top - 50, top], dtype=np.int32)
    assert list(upper._blocks(indptr)) == [(0, 1), (1, 3)]
