"""Structured hexahedral meshes with named node and cell sets.

A mesh is built from rectangular blocks, each a tensor product of node lines
in x, y and z. Blocks that touch share nodes where their node lines coincide,
so a narrow plate bonded to the centre of a wide plate's end face is
conforming as long as its y lines are a subset of the wide plate's. Nodes are
numbered with x slowest, then y, then z, which keeps the stiffness bandwidth
small for long, slender structures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .elements.hex8 import NODE_SIGNS

__all__ = ["Block", "Mesh", "mesh_blocks"]

#: Coordinates are merged when they agree to this many metres.
_MERGE_DECIMALS = 9


@dataclass(frozen=True)
class Block:
    """A box of hexahedra given by its node lines.

    Attributes
    ----------
    x, y, z : ndarray, shape (n_x + 1,), (n_y + 1,), (n_z + 1,), m
        Strictly increasing node-line coordinates.
    name : str
        Name of the cell set holding this block's cells.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    name: str

    def __post_init__(self) -> None:
        for axis in ("x", "y", "z"):
            lines = np.asarray(getattr(self, axis), dtype=float)
            if lines.ndim != 1 or lines.size < 2 or np.any(np.diff(lines) <= 0.0):
                raise ValueError(
                    f"block {self.name!r}: {axis} node lines must be at least two strictly "
                    f"increasing values, got {lines}"
                )
            object.__setattr__(self, axis, lines)


@dataclass
class Mesh:
    """Nodes, hexahedral cells and named sets.

    Attributes
    ----------
    nodes : ndarray, shape (n_nodes, 3), m
    cells : ndarray, shape (n_cells, 8), int
        Node indices in the order of :data:`fe_core.hex8.NODE_SIGNS`.
    cell_sets : dict of str to ndarray of int
    node_sets : dict of str to ndarray of int
    """

    nodes: np.ndarray
    cells: np.ndarray
    cell_sets: dict[str, np.ndarray] = field(default_factory=dict)
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return self.nodes.shape[0]

    @property
    def n_cells(self) -> int:
        return self.cells.shape[0]

    @property
    def cell_coords(self) -> np.ndarray:
        """Node coordinates per cell, shape (n_cells, 8, 3), m."""
        return self.nodes[self.cells]

    @property
    def centroids(self) -> np.ndarray:
        """Cell centroids, shape (n_cells, 3), m."""
        return self.cell_coords.mean(axis=1)

    def centroids_of(self, cells) -> np.ndarray:
        """Centroids of the cells ``cells`` (indices), shape (len(cells), 3), m: ``centroids[cells]`` without
        the whole mesh's (a patch's place is asked for thousands of times in the closure's exact search)."""
        return self.nodes[self.cells[cells]].mean(axis=1)

    def volume(self) -> float:
        """Total volume in m^3 (exact for parallelepiped cells)."""
        c = self.cell_coords
        a, b, d = c[:, 1] - c[:, 0], c[:, 3] - c[:, 0], c[:, 4] - c[:, 0]
        return float(np.abs(np.einsum("ei,ei->e", np.cross(a, b), d)).sum())

    def nodes_where(self, *, x=None, y=None, z=None, atol: float = 1e-9) -> np.ndarray:
        """Indices of nodes on the given coordinate planes (any subset of x, y, z), m."""
        mask = np.ones(self.n_nodes, dtype=bool)
        for axis, value in enumerate((x, y, z)):
            if value is not None:
                mask &= np.abs(self.nodes[:, axis] - value) <= atol
        return np.flatnonzero(mask)

    def nearest_node(self, point: Sequence[float], atol: float | None = 1e-9) -> int:
        """Index of the node closest to ``point``.

        Raises
        ------
        ValueError
            If ``atol`` is given and no node lies within it.
        """
        point = np.asarray(point, dtype=float)
        dist = np.linalg.norm(self.nodes - point, axis=1)
        i = int(np.argmin(dist))
        if atol is not None and dist[i] > atol:
            raise ValueError(
                f"no node at {point.tolist()} m (nearest is {self.nodes[i].tolist()}, "
                f"{dist[i]:.3g} m away)"
            )
        return i

    def add_cell_set(self, name: str, cells: np.ndarray) -> None:
        self.cell_sets[name] = np.asarray(cells, dtype=int)

    def add_node_set(self, name: str, nodes: np.ndarray) -> None:
        self.node_sets[name] = np.asarray(nodes, dtype=int)


def mesh_blocks(blocks: Sequence[Block]) -> Mesh:
    """Mesh a union of blocks, merging coincident nodes.

    Parameters
    ----------
    blocks : sequence of Block

    Returns
    -------
    Mesh
        With one cell set per block name. Node numbering is lexicographic in
        (x, y, z), x slowest; cells are ordered block by block, x slowest.
    """
    all_nodes, all_cells, names = [], [], []
    offset = 0
    for block in blocks:
        X, Y, Z = np.meshgrid(block.x, block.y, block.z, indexing="ij")
        nodes = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
        nx, ny, nz = X.shape
        ids = np.arange(nodes.shape[0]).reshape(nx, ny, nz)
        i, j, k = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij")
        i, j, k = i.ravel(), j.ravel(), k.ravel()
        corner = ((NODE_SIGNS + 1) // 2).astype(int)  # 0/1 offsets of the 8 corners
        cells = ids[i[:, None] + corner[:, 0], j[:, None] + corner[:, 1], k[:, None] + corner[:, 2]]
        all_nodes.append(nodes)
        all_cells.append(cells + offset)
        names.append((block.name, cells.shape[0]))
        offset += nodes.shape[0]

    raw_nodes = np.vstack(all_nodes)
    keys = np.round(raw_nodes, _MERGE_DECIMALS)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    # np.unique sorts rows lexicographically: x slowest, then y, then z.
    cells = inverse.reshape(-1)[np.vstack(all_cells)]
    mesh = Mesh(nodes=unique, cells=cells)
    start = 0
    for name, count in names:
        mesh.add_cell_set(name, np.arange(start, start + count))
        start += count
    return mesh

