"""Meshes with named sets, read through meshio (Gmsh ``.msh``, Abaqus ``.inp``, VTK ``.vtu``, ...).

Only the volume cells are elements; they must all be of one type (the element
registry :mod:`fe_core.elements` says which types exist). Named sets come from

- meshio's ``cell_sets``: Gmsh physical groups, Abaqus element sets. A set of
  volume cells is a *cell set*; every set (any dimension, e.g. a Gmsh physical
  surface) also gives the *node set* of its cells' nodes;
- meshio's ``point_sets``: Abaqus node sets;
- for formats without named sets (VTK ``.vtu``): every integer ``cell_data``
  array whose values are all 0 or 1 is the cell set of its 1-cells, every such
  ``point_data`` array the node set of its 1-nodes, named after the array.

Nodes used by no volume cell (Gmsh geometry points, loose nodes) are dropped;
:attr:`MeshFile.file_node` maps back to the file's node order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..mesh import Mesh

__all__ = ["MeshFile", "read_mesh", "MeshFileError"]

#: meshio sets that are bookkeeping, not the user's.
_IGNORED_SETS = ("gmsh:bounding_entities",)


class MeshFileError(ValueError):
    """A mesh file that cannot be used; the message names the file."""


@dataclass
class MeshFile:
    """The volume mesh of a file with its named sets.

    Attributes
    ----------
    path : Path
    mesh : Mesh
        Nodes (in the file's length unit), cells ``(n_cells, nodes per cell)`` in
        meshio's node order, cell sets and node sets (indices into ``mesh.nodes``).
    cell_type : str
        meshio cell type of the volume cells, e.g. ``"hexahedron"``, ``"tetra10"``.
    file_node : ndarray, shape (n_nodes,), int
        Index of each node in the file's node order (0-based, as meshio reads it).
    """

    path: Path
    mesh: Mesh
    cell_type: str
    file_node: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    def node_from_file(self, index: int) -> int:
        """The mesh node of a 0-based file node index; ``ValueError`` if it is in no volume cell."""
        hit = np.flatnonzero(self.file_node == index)
        if hit.size == 0:
            raise ValueError(f"node {index} is not a node of any volume cell of {self.path.name}")
        return int(hit[0])


def _dimension(cell_type: str) -> int:
    from meshio._mesh import topological_dimension

    return int(topological_dimension.get(cell_type, -1))


def read_mesh(path: str | Path) -> MeshFile:
    """Read a mesh file through meshio.

    Raises
    ------
    MeshFileError
        Unreadable file, no volume cells, or volume cells of several types;
        the message names the file.
    """
    import meshio

    path = Path(path)
    try:
        raw = meshio.read(path)
    except FileNotFoundError:
        raise MeshFileError(f"{path}: no such mesh file") from None
    except Exception as exc:  # meshio raises many kinds (ReadError, ValueError, KeyError, ...)
        raise MeshFileError(f"{path}: meshio cannot read it ({type(exc).__name__}: {exc})") from None

    volume = [k for k, block in enumerate(raw.cells) if _dimension(block.type) == 3]
    if not volume:
        types = sorted({b.type for b in raw.cells})
        raise MeshFileError(f"{path}: no volume cells (cell types {types}); the model needs solid elements")
    types = sorted({raw.cells[k].type for k in volume})
    if len(types) > 1:
        raise MeshFileError(f"{path}: volume cells of several types {types}; one element type per mesh")
    cell_type = types[0]
    offsets, start = {}, 0
    for k in volume:
        offsets[k] = start
        start += len(raw.cells[k].data)
    cells_file = np.vstack([raw.cells[k].data for k in volume]).astype(np.int64)

    used = np.unique(cells_file)
    new_index = np.full(len(raw.points), -1, dtype=np.int64)
    new_index[used] = np.arange(used.size)
    points = np.asarray(raw.points, dtype=float)
    if points.shape[1] != 3:
        raise MeshFileError(f"{path}: nodes have {points.shape[1]} coordinates; a solid mesh needs x, y, z")
    mesh = Mesh(nodes=points[used], cells=new_index[cells_file])

    def node_set(file_nodes) -> np.ndarray:
        mapped = new_index[np.unique(np.asarray(file_nodes, dtype=np.int64))]
        return mapped[mapped >= 0]

    sets = {k: v for k, v in raw.cell_sets.items() if k not in _IGNORED_SETS}
    for name, data in _vtk_sets(raw.cell_data).items():
        sets.setdefault(name, data)
    for name, per_block in sets.items():
        vol = [offsets[k] + np.asarray(per_block[k], dtype=np.int64) for k in volume
               if k < len(per_block) and per_block[k] is not None and len(per_block[k])]
        if vol:
            mesh.add_cell_set(name, np.unique(np.concatenate(vol)))
        nodes = [np.asarray(raw.cells[k].data)[np.asarray(idx, dtype=np.int64)].ravel()
                 for k, idx in enumerate(per_block) if idx is not None and len(idx)]
        if nodes:
            mesh.add_node_set(name, node_set(np.concatenate(nodes)))
    point_sets = dict(raw.point_sets)
    for name, values in raw.point_data.items():
        values = np.asarray(values)
        if values.ndim == 1 and values.dtype.kind in "iub" and np.isin(values, (0, 1)).all():
            point_sets.setdefault(name, np.flatnonzero(values))
    for name, nodes in point_sets.items():
        mesh.add_node_set(name, node_set(nodes))
    return MeshFile(path=path, mesh=mesh, cell_type=cell_type, file_node=used)


def _vtk_sets(cell_data: dict) -> dict:
    """Integer 0/1 cell-data arrays as per-block index lists (the VTK convention above)."""
    out = {}
    for name, blocks in cell_data.items():
        if name.startswith("gmsh:"):
            continue
        arrays = [np.asarray(b) for b in blocks]
        if all(a.ndim == 1 and a.dtype.kind in "iub" and np.isin(a, (0, 1)).all() for a in arrays):
            out[name] = [np.flatnonzero(a) for a in arrays]
    return out
