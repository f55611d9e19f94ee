"""Matrices exported by another FE program: per-segment stiffness and mass, a remainder, a DOF table.

Matrix files: Matrix Market ``.mtx`` (``scipy.io.mmread``) or SciPy's sparse
``.npz`` (``scipy.sparse.save_npz`` / ``load_npz``). The DOF table is a CSV file
with the header ``node,direction`` and one row per matrix row: the node id (any
integer the exporting program uses) and the direction ``x``, ``y`` or ``z``
(or 1, 2, 3). An optional node table (CSV, header ``node,x,y,z``) gives each node's
coordinates in metres: the closure then places its effects and measures how far
their evidence spreads.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import scipy.io
import scipy.sparse as sp

__all__ = ["read_matrix", "read_dof_table", "read_node_table", "check_symmetric_psd", "DIRECTIONS", "MatrixFileError"]

DIRECTIONS = {"x": 0, "y": 1, "z": 2, "1": 0, "2": 1, "3": 2}

#: Relative asymmetry ``max |A - A^T| / max |A|`` above which a matrix is refused.
SYMMETRY_RTOL = 1e-10
#: Most negative eigenvalue, relative to the largest, still taken as round-off of a PSD matrix.
PSD_RTOL = 1e-10
#: Largest size checked by a dense eigenvalue decomposition (larger ones: necessary conditions).
DENSE_CHECK_MAX = 3000


class MatrixFileError(ValueError):
    """A matrix or DOF-table file that cannot be used; the message names the file."""


def read_matrix(path: str | Path) -> sp.csr_matrix:
    """A sparse matrix from ``.mtx`` or ``.npz``, as CSR of floats."""
    path = Path(path)
    if not path.exists():
        raise MatrixFileError(f"{path}: no such matrix file")
    try:
        if path.suffix == ".mtx":
            A = scipy.io.mmread(str(path))
        elif path.suffix == ".npz":
            A = sp.load_npz(path)
        else:
            raise MatrixFileError(f"{path}: unknown matrix format {path.suffix!r}; use .mtx or .npz")
    except MatrixFileError:
        raise
    except Exception as exc:
        raise MatrixFileError(f"{path}: cannot read the matrix ({type(exc).__name__}: {exc})") from None
    A = sp.csr_matrix(A, dtype=float)
    if A.shape[0] != A.shape[1]:
        raise MatrixFileError(f"{path}: matrix is {A.shape[0]} x {A.shape[1]}, not square")
    if not np.all(np.isfinite(A.data)):
        raise MatrixFileError(f"{path}: matrix has non-finite entries")
    return A


def _csv_rows(path: Path, what: str, header: list[str]) -> list[list[str]]:
    """The rows of a CSV table, its header checked (:class:`MatrixFileError` naming the file otherwise)."""
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise MatrixFileError(f"{path}: cannot read {what} ({exc.strerror})") from None
    if not rows or [c.strip() for c in rows[0]] != header:
        raise MatrixFileError(f"{path}: {what} needs the header '{','.join(header)}'")
    return rows


def read_dof_table(path: str | Path) -> np.ndarray:
    """The DOF table, shape (n, 2), int: node id and direction (0, 1, 2) of each matrix row."""
    path = Path(path)
    rows = _csv_rows(path, "the DOF table", ["node", "direction"])
    out = np.empty((len(rows) - 1, 2), dtype=np.int64)
    for i, row in enumerate(rows[1:]):
        try:
            node, direction = (c.strip() for c in row)
            out[i] = int(node), DIRECTIONS[direction.lower()]
        except (ValueError, KeyError):
            raise MatrixFileError(f"{path}: line {i + 2}: expected 'node,direction' with an integer node and "
                                  f"direction x, y or z, got {','.join(row)!r}") from None
    keys = out[:, 0] * 3 + out[:, 1]
    uniq, counts = np.unique(keys, return_counts=True)
    if np.any(counts > 1):
        k = uniq[counts > 1][0]
        raise MatrixFileError(f"{path}: node {k // 3} direction {'xyz'[k % 3]} appears {counts.max()} times")
    return out


def read_node_table(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The node table: node ids, shape (k,), int, ascending, and their coordinates, shape (k, 3), m.

    A CSV file with the header ``node,x,y,z`` and one row per node: an integer id (the DOF
    table's) and three finite numbers. A malformed row or a repeated node is refused
    (:class:`MatrixFileError` naming the file and the line).
    """
    path = Path(path)
    rows = _csv_rows(path, "the node table", ["node", "x", "y", "z"])
    ids = np.empty(len(rows) - 1, dtype=np.int64)
    xyz = np.empty((len(rows) - 1, 3))
    line_of: dict[int, int] = {}
    for i, row in enumerate(rows[1:]):
        try:
            node, *coords = (c.strip() for c in row)
            ids[i], xyz[i] = int(node), [float(c) for c in coords]
        except ValueError:
            raise MatrixFileError(f"{path}: line {i + 2}: expected 'node,x,y,z' with an integer node and three "
                                  f"numbers, got {','.join(row)!r}") from None
        if not np.all(np.isfinite(xyz[i])):
            raise MatrixFileError(f"{path}: line {i + 2}: node {ids[i]} has a non-finite coordinate "
                                  f"{','.join(row[1:])!r}")
        if int(ids[i]) in line_of:
            raise MatrixFileError(f"{path}: line {i + 2}: node {ids[i]} is listed again (first on line "
                                  f"{line_of[int(ids[i])]})")
        line_of[int(ids[i])] = i + 2
    order = np.argsort(ids)
    return ids[order], xyz[order]


def check_symmetric_psd(A: sp.csr_matrix, name: str) -> None:
    """Refuse a matrix that is not symmetric or not positive semidefinite (``ValueError`` naming it).

    Symmetry: ``max |A - A^T| <= SYMMETRY_RTOL max |A|``. Semidefiniteness: exact
    (dense eigenvalues) up to ``DENSE_CHECK_MAX`` rows; above that the necessary
    conditions ``A_ii >= 0`` and ``|A_ij| <= sqrt(A_ii A_jj)``.
    """
    scale = float(abs(A).max()) if A.nnz else 0.0
    if scale == 0.0:
        return
    asym = float(abs(A - A.T).max()) if (A - A.T).nnz else 0.0
    if asym > SYMMETRY_RTOL * scale:
        raise ValueError(f"{name} is not symmetric: max |A - A^T| = {asym:.3g}, {asym / scale:.2g} of max |A|")
    d = A.diagonal()
    if np.any(d < -PSD_RTOL * scale):
        i = int(np.argmin(d))
        raise ValueError(f"{name} is not positive semidefinite: diagonal entry {i} is {d[i]:.6g}")
    if A.shape[0] <= DENSE_CHECK_MAX:
        lowest = float(np.linalg.eigvalsh(A.toarray())[0])
        if lowest < -PSD_RTOL * scale * A.shape[0]:
            raise ValueError(f"{name} is not positive semidefinite: lowest eigenvalue {lowest:.6g} "
                             f"(largest entry {scale:.6g})")
        return
    coo = A.tocoo()
    bound = np.sqrt(np.clip(d[coo.row], 0, None) * np.clip(d[coo.col], 0, None))
    bad = np.abs(coo.data) > bound * (1 + 1e-8) + PSD_RTOL * scale
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} is not positive semidefinite: |A[{coo.row[k]}, {coo.col[k]}]| exceeds "
                         "sqrt(A_ii A_jj)")
