"""Structured tetrahedral meshes of a box, for element tests and convergence studies.

Each hexahedron of an ``nx x ny x nz`` grid is split into the six Kuhn tetrahedra
around its main diagonal; the split is the same in every cell, so the mesh is
conforming. Quadratic meshes add one node per unique edge at its midpoint, in
meshio's ``tetra10`` order (see :mod:`fe_core.elements.tet10`).
"""

from __future__ import annotations

from itertools import permutations

import numpy as np

from .elements.tet10 import EDGES

__all__ = ["box_tets"]


def box_tets(size, cells, order: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A box ``[0, lx] x [0, ly] x [0, lz]`` meshed in tetrahedra.

    Parameters
    ----------
    size : (lx, ly, lz), m
    cells : (nx, ny, nz), int
        Hexahedra per direction, each split into 6 tetrahedra.
    order : {1, 2}
        Linear (meshio "tetra") or quadratic (meshio "tetra10") cells.

    Returns
    -------
    nodes : ndarray, shape (n_nodes, 3), m
    cells : ndarray, shape (6 nx ny nz, 4 or 10), int
        Positively oriented (det J > 0).
    """
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    n = np.asarray(cells, dtype=int)
    if n.shape != (3,) or np.any(n < 1):
        raise ValueError(f"cells must be three positive counts, got {cells!r}")
    axes = [np.linspace(0.0, float(s), k + 1) for s, k in zip(size, n)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    nodes = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    index = np.arange(nodes.shape[0]).reshape(n + 1)

    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(c) for c in n), indexing="ij"))
    tets = []
    for perm in permutations(range(3)):
        # The Kuhn path 000 -> e_a -> e_a + e_b -> 111 for one axis order (a, b, c).
        offset = np.zeros(3, dtype=int)
        path = [offset.copy()]
        for axis in perm:
            offset[axis] += 1
            path.append(offset.copy())
        tets.append(np.column_stack([index[i + o[0], j + o[1], k + o[2]] for o in path]))
    tets = np.concatenate(tets)
    edge = nodes[tets[:, 1:]] - nodes[tets[:, :1]]
    negative = np.linalg.det(edge) < 0.0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    if order == 1:
        return nodes, tets

    pairs = np.sort(tets[:, EDGES], axis=2).reshape(-1, 2)  # (6 n_tets, 2)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mid = 0.5 * (nodes[unique[:, 0]] + nodes[unique[:, 1]])
    edge_nodes = nodes.shape[0] + inverse.reshape(-1, 6)
    return np.vstack([nodes, mid]), np.hstack([tets, edge_nodes])
