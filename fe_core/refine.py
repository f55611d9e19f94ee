"""Uniform refinement of a quadratic tetrahedral mesh, each ten-node tetrahedron into eight, and of a hexahedral one,
each eight-node hexahedron into eight (:func:`refine_hex8`).

The finer mesh of the same structure is how the tool sizes the model's own discretisation error (the misfit a
model of this mesh leaves against its own refinement, :mod:`fe_core.model_error`). Each cell is split as in the
red refinement of tetrahedra (Bey 1995): the four corner tetrahedra and four round the shortest diagonal of the
inner octahedron, all on the cell's corner and mid-edge nodes; each child's mid-edge nodes are placed by the
parent's own quadratic map, so a curved cell (mid-edge nodes on a CAD surface) stays on its surface and the
refined mesh is conforming (a node of a shared face or edge is placed by the same six or three nodes on both
sides). Node order is VTK's (:mod:`fe_core.elements.tet10`); the coarse nodes keep their indices, the new ones
follow. A child cell belongs to its parent's cell sets; a new node to a node set when it lies on a cell face whose
six nodes are all in the set (a clamped face stays clamped, a set of single points gains nothing).
"""

from __future__ import annotations

import numpy as np

from .elements import hex8, tet10
from .mesh import Mesh

__all__ = ["refine_tet10", "refine_hex8", "CHILDREN_PER_CELL"]

CHILDREN_PER_CELL = 8

#: Reference coordinates of the ten nodes (corners, then the mid-edge nodes of tet10.EDGES).
_REF = np.vstack([np.zeros(3), np.eye(3)])
_REF = np.vstack([_REF, 0.5 * (_REF[tet10.EDGES[:, 0]] + _REF[tet10.EDGES[:, 1]])])

#: The four corner children (parent local nodes; each as oriented as its parent).
_CORNERS = np.array([[0, 4, 6, 7], [4, 1, 5, 8], [6, 5, 2, 9], [7, 8, 9, 3]])
#: The inner octahedron's three diagonals (mid-edge nodes of opposite edges) and, for each, the cycle of the other
#: four round it.
_DIAGONALS = np.array([[4, 9], [5, 7], [6, 8]])
_CYCLES = np.array([[5, 8, 7, 6], [4, 6, 9, 8], [4, 5, 9, 7]])
#: The four faces as their six local nodes (three corners, three mid-edge nodes).
_FACES = np.array([[0, 1, 2, 4, 5, 6], [0, 1, 3, 4, 8, 7], [1, 2, 3, 5, 9, 8], [0, 2, 3, 6, 9, 7]])
#: A child's six edges as pairs of its four corners, in tet10.EDGES order.
_CHILD_EDGES = tet10.EDGES


def _children(diagonal: int) -> np.ndarray:
    """The eight children (8, 4) of parent local nodes for the octahedron split along ``diagonal`` (0, 1, 2)."""
    a, b = _DIAGONALS[diagonal]
    c = _CYCLES[diagonal]
    inner = np.array([[a, b, c[k], c[(k + 1) % 4]] for k in range(4)])
    return np.vstack([_CORNERS, inner])


def _signed_volumes(ref_children: np.ndarray) -> np.ndarray:
    x = _REF[ref_children]  # (8, 4, 3)
    return np.linalg.det(x[:, 1:] - x[:, :1]) / 6.0


#: For each diagonal, the eight children with the inner four oriented as the parent (reference volume 1/48 each).
_SPLITS = []
for _d in range(3):
    _ch = _children(_d)
    _neg = _signed_volumes(_ch) < 0
    _ch[_neg] = _ch[_neg][:, [1, 0, 2, 3]]
    assert np.allclose(_signed_volumes(_ch), 1.0 / 48.0)
    _SPLITS.append(_ch)
_SPLITS = np.array(_SPLITS)  # (3, 8, 4)

#: The 25 distinct edges of the children (local node pairs, sorted), and for each the faces (of _FACES) it lies in.
_EDGE_LIST = sorted({tuple(sorted((int(ch[i]), int(ch[j])))) for s in _SPLITS for ch in s for i, j in _CHILD_EDGES})
_EDGE_INDEX = {e: k for k, e in enumerate(_EDGE_LIST)}
_EDGE_FACES = np.array([[set(e) <= set(f) for f in _FACES] for e in _EDGE_LIST])  # (n_edges, 4)
#: The 24 edges every split has, and each split's diagonal (indices into _EDGE_LIST).
_COMMON = np.array([k for k, e in enumerate(_EDGE_LIST) if all(
    any(set(e) == {int(ch[i]), int(ch[j])} for ch in s for i, j in _CHILD_EDGES) for s in _SPLITS)])
_DIAGONAL_EDGE = np.array([_EDGE_LIST.index(tuple(sorted(map(int, d)))) for d in _DIAGONALS])
_EDGE_TABLE = np.full((10, 10), -1, dtype=np.int64)  # sorted local pair -> its index in _EDGE_LIST
for _k, (_i, _j) in enumerate(_EDGE_LIST):
    _EDGE_TABLE[_i, _j] = _k


def refine_tet10(mesh: Mesh) -> Mesh:
    """The mesh with each tet10 cell split into eight (see the module docstring).

    Returns a new :class:`fe_core.mesh.Mesh`: nodes ``(n_nodes + n_new, 3)`` with the coarse nodes first and in
    their order, cells ``(8 n_cells, 10)`` with cell ``8 e + k`` the ``k``-th child of cell ``e``, cell sets and
    node sets carried over.
    """
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != tet10.NODES:
        raise ValueError(f"refine_tet10 refines ten-node tetrahedra; the cells have shape {cells.shape}")
    nodes = np.asarray(mesh.nodes, dtype=float)
    n_cells, n_nodes = cells.shape[0], nodes.shape[0]
    # The octahedron's shortest diagonal, per cell (straight-edge lengths: the split is a choice, not geometry).
    mids = nodes[cells[:, 4:]]  # (n, 6, 3): local nodes 4..9
    lengths = np.stack([np.linalg.norm(mids[:, a - 4] - mids[:, b - 4], axis=1) for a, b in _DIAGONALS], axis=1)
    diagonal = np.argmin(lengths, axis=1)
    local = _SPLITS[diagonal]  # (n, 8, 4) parent local nodes of each child's corners
    # Each child edge as a (cell, local pair) -> its distinct-edge index; new node keys are global node pairs.
    a = local[:, :, _CHILD_EDGES[:, 0]]
    b = local[:, :, _CHILD_EDGES[:, 1]]  # (n, 8, 6)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    edge_of = _EDGE_TABLE[lo, hi]  # (n, 8, 6) index into _EDGE_LIST
    # Each cell's 25 distinct child edges (24 common to every split and its diagonal) as global node pairs: the new
    # nodes, deduplicated across cells.
    used = np.concatenate([np.broadcast_to(_COMMON, (n_cells, _COMMON.size)), _DIAGONAL_EDGE[diagonal][:, None]],
                          axis=1)  # (n, 25) indices into _EDGE_LIST
    pairs = np.array(_EDGE_LIST)[used]  # (n, 25, 2) local pairs
    rows = np.arange(n_cells)[:, None]
    g = np.sort(np.stack([cells[rows, pairs[..., 0]], cells[rows, pairs[..., 1]]], axis=2), axis=2)
    _, first, inverse = np.unique(g.reshape(-1, 2), axis=0, return_index=True, return_inverse=True)
    # Positions by the parent's quadratic map at the edge's reference midpoint (from the first cell holding it).
    cell_of = first // used.shape[1]
    xi = 0.5 * (_REF[pairs.reshape(-1, 2)[first, 0]] + _REF[pairs.reshape(-1, 2)[first, 1]])
    N = tet10.shape_functions(xi)  # (n_new, 10)
    new_xyz = np.einsum("ka,kaj->kj", N, nodes[cells[cell_of]])
    new_nodes = np.full((n_cells, len(_EDGE_LIST)), -1, dtype=np.int64)  # each cell's edge -> its new node
    new_nodes[rows, used] = n_nodes + inverse.reshape(n_cells, used.shape[1])
    # The children: corners from the parent, mid-edge nodes from the new nodes.
    child_corners = np.take_along_axis(cells[:, None, :].repeat(8, axis=1), local, axis=2)  # (n, 8, 4)
    child_mids = np.take_along_axis(new_nodes[:, None, :].repeat(8, axis=1), edge_of, axis=2)
    out_cells = np.concatenate([child_corners, child_mids], axis=2).reshape(-1, tet10.NODES)
    out = Mesh(nodes=np.vstack([nodes, new_xyz]), cells=out_cells)
    children = np.arange(CHILDREN_PER_CELL)
    for name, idx in mesh.cell_sets.items():
        idx = np.asarray(idx, dtype=np.int64)
        out.add_cell_set(name, (CHILDREN_PER_CELL * idx[:, None] + children[None, :]).ravel())
    faces = cells[:, _FACES]  # (n, 4, 6)
    for name, idx in mesh.node_sets.items():
        member = np.zeros(n_nodes, bool)
        member[np.asarray(idx, dtype=np.int64)] = True
        face_in = member[faces].all(axis=2)  # (n, 4)
        on = (face_in[:, None, :] & _EDGE_FACES[None]).any(axis=2) & (new_nodes >= 0)  # (n, 27)
        added = np.unique(new_nodes[on])
        out.add_node_set(name, np.concatenate([np.asarray(idx, dtype=np.int64), added]))
    return out


#: The 27 points of a hexahedron's refinement in reference coordinates (-1, 0, 1 along each axis).
_GRID = np.array([[x, y, z] for z in (-1, 0, 1) for y in (-1, 0, 1) for x in (-1, 0, 1)], dtype=float)
#: For each grid point, the parent corners whose signs it shares on its nonzero coordinates: one (a corner), two (an
#: edge's midpoint), four (a face's centre) or eight (the centre).
_TOUCH = [np.flatnonzero(np.all((hex8.NODE_SIGNS == g) | (g == 0), axis=1)) for g in _GRID]
#: Each child's eight corners as grid points (octant by octant, oriented as the parent).
_HEX_CHILDREN = np.array([[int(np.flatnonzero(np.all(_GRID == (np.array(o) - 1) + (sgn + 1) // 2, axis=1))[0])
                           for sgn in hex8.NODE_SIGNS] for o in np.ndindex(2, 2, 2)])


def refine_hex8(mesh: Mesh) -> Mesh:
    """The mesh with each eight-node hexahedron split into eight by its trilinear map (edge midpoints, face centres
    and its centre added, shared ones once): cells ``8 e + k`` the children of cell ``e``, each oriented as its
    parent, the coarse nodes first and in their order, cell sets carried over, a new node added to a node set when
    it lies on a cell face whose four corners are all in the set (as :func:`refine_tet10`)."""
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != hex8.NODES:
        raise ValueError(f"refine_hex8 refines eight-node hexahedra; the cells have shape {cells.shape}")
    nodes = np.asarray(mesh.nodes, dtype=float)
    n_cells, n_nodes = cells.shape[0], nodes.shape[0]
    N = hex8.shape_functions(_GRID)                                    # (27, 8)
    grid_node = np.empty((n_cells, _GRID.shape[0]), dtype=np.int64)
    new_xyz, next_id = [], n_nodes
    for size in (1, 2, 4, 8):
        points = [g for g, t in enumerate(_TOUCH) if t.size == size]
        if size == 1:
            grid_node[:, points] = cells[:, [int(_TOUCH[g][0]) for g in points]]
            continue
        keys = np.sort(np.stack([cells[:, _TOUCH[g]] for g in points], axis=1), axis=2)   # (n, k, size)
        unique, first, inverse = np.unique(keys.reshape(-1, size), axis=0, return_index=True, return_inverse=True)
        grid_node[:, points] = next_id + inverse.reshape(n_cells, len(points))
        cell_of, which = np.divmod(first, len(points))
        new_xyz.append(np.einsum("ka,kaj->kj", N[np.asarray(points)[which]], nodes[cells[cell_of]]))
        next_id += unique.shape[0]
    out = Mesh(nodes=np.vstack([nodes, *new_xyz]), cells=grid_node[:, _HEX_CHILDREN].reshape(-1, hex8.NODES))
    children = np.arange(CHILDREN_PER_CELL)
    for name, idx in mesh.cell_sets.items():
        idx = np.asarray(idx, dtype=np.int64)
        out.add_cell_set(name, (CHILDREN_PER_CELL * idx[:, None] + children[None, :]).ravel())
    faces = [(d, sgn) for d in range(3) for sgn in (-1, 1)]
    for name, idx in mesh.node_sets.items():
        member = np.zeros(n_nodes, bool)
        member[np.asarray(idx, dtype=np.int64)] = True
        on = np.zeros_like(grid_node, dtype=bool)
        for d, sgn in faces:
            corners = np.flatnonzero(hex8.NODE_SIGNS[:, d] == sgn)
            whole = member[cells[:, corners]].all(axis=1)                      # (n,)
            on |= whole[:, None] & (_GRID[:, d] == sgn)[None, :]
        added = np.unique(grid_node[on & (grid_node >= n_nodes)])
        out.add_node_set(name, np.concatenate([np.asarray(idx, dtype=np.int64), added]))
    return out
