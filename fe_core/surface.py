"""The outer surface of a solid mesh and the placement of sensors and loads, for pictures.

The boundary of a mesh of solid cells is the set of cell faces that belong to
exactly one cell. Faces are given by their corner nodes only (a tet10 cell is
drawn as its tet4 corners: the mid-side nodes of straight-sided cells add no
shape to a flat picture). Every face is oriented with its normal pointing out
of its cell, so a viewer can drop the faces that look away from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .assembly import DOFS_PER_NODE

__all__ = ["FACES", "cell_type_of", "boundary_faces", "face_normals", "DofArrows", "dof_arrows"]

#: Corner-node faces of each cell type (VTK node order), local node indices.
FACES: dict[str, np.ndarray] = {
    "tetra": np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]),
    "tetra10": np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]),
    "hexahedron": np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]),
}
_CORNERS = {"tetra": 4, "tetra10": 4, "hexahedron": 8}


def cell_type_of(cells: np.ndarray) -> str:
    """meshio cell type of a cell array from its nodes per cell (8: hex8, 4: tet4, 10: tet10).

    Raises ``ValueError`` for any other width.
    """
    from .elements import ELEMENTS

    width = np.asarray(cells).shape[1]
    for name, module in ELEMENTS.items():
        if module.NODES == width:
            return name
    raise ValueError(f"no element family has {width} nodes per cell (known: "
                     f"{', '.join(f'{n} ({m.NODES})' for n, m in ELEMENTS.items())})")


def face_normals(nodes: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted normals of planar polygons, shape (n_faces, 3): length = area, m^2.

    The normal follows the right-hand rule over the face's node order (Newell's formula,
    exact for planar polygons).
    """
    p = nodes[faces]  # (n, k, 3)
    q = np.roll(p, -1, axis=1)
    return 0.5 * np.cross(p, q).sum(axis=1)


def boundary_faces(nodes: np.ndarray, cells: np.ndarray, cell_type: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Faces on the outer surface of a solid mesh, oriented outward.

    Parameters
    ----------
    nodes : ndarray, shape (n_nodes, 3), m
    cells : ndarray, shape (n_cells, nodes per cell), int
        meshio (VTK) node order.
    cell_type : str, optional
        ``"hexahedron"``, ``"tetra"`` or ``"tetra10"``; from the cells' width when omitted.

    Returns
    -------
    faces : ndarray, shape (n_faces, 3 or 4), int
        Corner nodes of each boundary face, ordered so that the right-hand normal points
        out of the cell.
    owner : ndarray, shape (n_faces,), int
        The cell each face belongs to.
    """
    cell_type = cell_type or cell_type_of(cells)
    local = FACES[cell_type]
    cells = np.asarray(cells)
    all_faces = cells[:, local].reshape(-1, local.shape[1])  # (n_cells * f, k)
    owner = np.repeat(np.arange(cells.shape[0]), local.shape[0])
    _, index, counts = np.unique(np.sort(all_faces, axis=1), axis=0, return_index=True, return_counts=True)
    keep = np.sort(index[counts == 1])
    faces, owner = all_faces[keep], owner[keep]
    # Outward: the normal points from the cell's centroid towards the face's.
    centroid = nodes[cells[:, :_CORNERS[cell_type]]].mean(axis=1)
    inward = np.einsum("ij,ij->i", face_normals(nodes, faces), nodes[faces].mean(axis=1) - centroid[owner]) < 0
    faces[inward] = faces[inward, ::-1]
    return faces, owner


@dataclass
class DofArrows:
    """Where a free-DOF vector acts: one arrow per node it touches.

    Attributes
    ----------
    nodes : ndarray, shape (n,), int
    positions : ndarray, shape (n, 3), m
    directions : ndarray, shape (n, 3)
        Unit vectors (the vector's x, y, z entries at the node, normalised).
    weights : ndarray, shape (n,)
        Length of each node's (x, y, z) entries before normalising.
    """

    nodes: np.ndarray
    positions: np.ndarray
    directions: np.ndarray
    weights: np.ndarray


def dof_arrows(model, vector) -> DofArrows:
    """The nodes and directions of a free-DOF vector of a mesh model (a sensor's output
    vector, the excitation's load vector).

    Parameters
    ----------
    model : ParametricModel
        With a mesh.
    vector : array_like or sparse, shape (n_free,) or (n_free, 1)
    """
    if model.mesh is None:
        raise ValueError("the model has no mesh: its DOFs have no positions")
    v = vector.toarray().ravel() if hasattr(vector, "toarray") else np.asarray(vector, dtype=float).ravel()
    rows = np.flatnonzero(v)
    full = np.zeros((model.mesh.n_nodes, DOFS_PER_NODE))
    g = model.free_dofs[rows]
    np.add.at(full, (g // DOFS_PER_NODE, g % DOFS_PER_NODE), v[rows])
    nodes = np.unique(g // DOFS_PER_NODE)
    vec = full[nodes]
    weights = np.linalg.norm(vec, axis=1)
    return DofArrows(nodes, model.mesh.nodes[nodes], vec / weights[:, None], weights)
