"""CalculiX's output files: the matrices of ``*FREQUENCY, SOLVER=MATRIXSTORAGE`` (``.sti``, ``.mas``: the upper
triangle as ``row col value``, 1-based, after the deck's boundary conditions and equations; ``.dof``: one
``node.direction`` per row), the eigenvalue table and the complex nodal displacements of
``*STEADY STATE DYNAMICS`` with ``*NODE PRINT`` in ``.dat`` (each frequency's real part, then its imaginary
part).

Shell and beam elements are expanded by ccx into solids: their rows carry the shell node's id once per
expanded node (top and bottom for S4, C3D8I bubble DOFs under new ids), and the shell node's
displacement is the mean of its rows (:func:`node_dof_weights`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import scipy.sparse as sp

__all__ = ["read_storage", "read_eigenfrequencies", "read_steady_state", "node_dof_weights", "ResultError"]


class ResultError(ValueError):
    """An output file of ccx that cannot be read; the message names the file."""


def _read_triangle(path: Path, n: int) -> sp.csr_matrix:
    try:
        a = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ResultError(f"{path}: cannot read the matrix ({exc})") from None
    if a.shape[1] != 3:
        raise ResultError(f"{path}: expected 'row column value' lines")
    i, j = a[:, 0].astype(np.int64) - 1, a[:, 1].astype(np.int64) - 1
    if i.size and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise ResultError(f"{path}: indices outside 1..{n} (the .dof table's rows)")
    off = i != j
    A = sp.coo_matrix((np.concatenate([a[:, 2], a[off, 2]]), (np.concatenate([i, j[off]]),
                                                               np.concatenate([j, i[off]]))), shape=(n, n))
    return A.tocsr()


def read_storage(folder: str | Path, job: str) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray]:
    """(K, M, labels): the stored stiffness and mass and, per row, ``(node, direction 1..3)``."""
    folder = Path(folder)
    dof = folder / f"{job}.dof"
    labels = []
    try:
        lines = dof.read_text().split()
    except OSError as exc:
        raise ResultError(f"{dof}: cannot read the DOF table ({exc.strerror})") from None
    for k, text in enumerate(lines):
        node, _, d = text.partition(".")
        try:
            labels.append((int(node), int(d)))
        except ValueError:
            raise ResultError(f"{dof}: row {k + 1}: expected node.direction, got {text!r}") from None
    labels = np.array(labels, dtype=np.int64).reshape(-1, 2)
    n = labels.shape[0]
    return _read_triangle(folder / f"{job}.sti", n), _read_triangle(folder / f"{job}.mas", n), labels


def node_dof_weights(labels: np.ndarray, node: int, direction: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, weights) of a node's displacement in ``direction`` (1..3): the mean over its rows."""
    rows = np.flatnonzero((labels[:, 0] == node) & (labels[:, 1] == direction))
    return rows, np.full(rows.size, 1.0 / max(rows.size, 1))


_FLOAT = r"[-+]?\d*\.?\d+(?:[eEdD][-+]?\d+)?"


def read_eigenfrequencies(path: str | Path) -> np.ndarray:
    """The natural frequencies in Hz (the cycles/time column of the first eigenvalue table)."""
    text = Path(path).read_text(errors="replace")
    at = text.find("E I G E N V A L U E   O U T P U T")
    if at < 0:
        raise ResultError(f"{path}: no eigenvalue table")
    out = []
    for line in text[at:].splitlines()[6:]:
        parts = line.split()
        if len(parts) != 5 or not parts[0].isdigit():
            if out:
                break
            continue
        out.append(float(parts[3]))
    return np.array(out)


def read_steady_state(path: str | Path) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """(frequencies in Hz, {node: complex displacements, shape (n_frequencies, 3)}) of a ``.dat`` file."""
    text = Path(path).read_text(errors="replace")
    head = re.compile(r"displacements \(vx,vy,vz\) for set \S+ and time\s+(" + _FLOAT + ")")
    blocks = []
    lines = text.splitlines()
    k = 0
    while k < len(lines):
        m = head.search(lines[k])
        if not m:
            k += 1
            continue
        values = {}
        k += 1
        while k < len(lines) and not head.search(lines[k]):
            parts = lines[k].split()
            if len(parts) == 4 and parts[0].isdigit():
                values[int(parts[0])] = [float(p) for p in parts[1:]]
            elif parts and values:
                break
            k += 1
        blocks.append((float(m.group(1)), values))
    if len(blocks) % 2:
        raise ResultError(f"{path}: {len(blocks)} displacement blocks; expected pairs (real, imaginary)")
    freqs = np.array([blocks[i][0] for i in range(0, len(blocks), 2)])
    nodes = sorted(blocks[0][1]) if blocks else []
    out = {n: np.array([np.array(blocks[i][1][n]) + 1j * np.array(blocks[i + 1][1][n])
                        for i in range(0, len(blocks), 2)]) for n in nodes}
    return freqs, out
