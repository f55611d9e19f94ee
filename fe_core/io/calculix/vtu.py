"""The deck's mesh as a VTK grid (``model.vtu``): its elements by type, each cell's segment and factors, and the
updated model's modes at the deck's nodes (a shell node's displacement: the mean of its rows in ccx's
matrices, as ccx reports it). Element types meshio has no name for are left out and counted."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..vtu import _per_cell, mode_field_name
from .deck import Deck

__all__ = ["DeckView", "deck_view", "deck_vtu", "MESHIO_TYPES"]

#: ccx element types and their meshio cell types (corner nodes first, as both order them).
MESHIO_TYPES = {"S3": "triangle", "S4": "quad", "S4R": "quad", "S6": "triangle6", "S8": "quad8", "S8R": "quad8",
                "M3D4": "quad", "M3D8": "quad8", "CPS4": "quad", "CPE4": "quad", "B31": "line", "B32": "line3",
                "T3D2": "line", "C3D4": "tetra", "C3D10": "tetra10", "C3D6": "wedge", "C3D8": "hexahedron",
                "C3D8I": "hexahedron", "C3D8R": "hexahedron", "C3D20": "hexahedron20", "C3D20R": "hexahedron20"}


@dataclass
class DeckView:
    """What ``model.vtu`` needs of a deck model: points, cell blocks, segments and the node-from-rows map."""

    node_ids: np.ndarray
    points: np.ndarray                       # (n_nodes, 3)
    blocks: list                             # [(meshio type, connectivity (k, nodes) as point indices)]
    segments: list                           # per block: segment index of each cell (-1: none)
    rows_to_nodes: sp.csr_matrix             # (3 n_nodes, n_rows): node displacement = mean of its rows
    skipped: dict                            # element type -> number of elements left out


def deck_view(deck: Deck, elsets: list[str], labels: np.ndarray) -> DeckView:
    """The view of a deck whose segments are ``elsets``, with ccx's row labels ``(node, direction 1..3)``."""
    ids = np.array(sorted(deck.nodes), dtype=np.int64)
    index = {int(n): i for i, n in enumerate(ids)}
    points = np.array([deck.nodes[n][:3] for n in ids], float).reshape(-1, 3)
    seg_of = {}
    for k, name in enumerate(elsets):
        for e in deck.elsets.get(name.upper(), []):
            seg_of.setdefault(e, k)
    by_type, skipped = {}, {}
    for e, (etype, nodes) in sorted(deck.elements.items()):
        cell = MESHIO_TYPES.get(etype)
        if cell is None:
            skipped[etype] = skipped.get(etype, 0) + 1
            continue
        by_type.setdefault(cell, ([], []))
        by_type[cell][0].append([index[n] for n in nodes])
        by_type[cell][1].append(seg_of.get(e, -1))
    blocks = [(t, np.array(c, dtype=np.int64)) for t, (c, _) in by_type.items()]
    segments = [np.array(s, dtype=np.int64) for _, s in by_type.values()]
    rows, cols, count = [], [], {}
    for r, (node, d) in enumerate(labels):
        if int(node) in index and 1 <= d <= 3:
            key = 3 * index[int(node)] + int(d) - 1
            rows.append(key)
            cols.append(r)
            count[key] = count.get(key, 0) + 1
    vals = [1.0 / count[k] for k in rows]
    R = sp.csr_matrix((vals, (rows, cols)), shape=(3 * ids.size, labels.shape[0]))
    return DeckView(ids, points, blocks, segments, R, skipped)


def deck_vtu(model, view: DeckView, alpha, gamma=None, n_modes: int = 6):
    """A meshio grid of the deck with ``segment``, ``alpha`` (``gamma``) per cell and the first modes."""
    import meshio

    cell_data = {"segment": view.segments,
                 "alpha": [_per_cell(s, alpha, model.n_segments, "alpha") for s in view.segments]}
    if gamma is not None:
        cell_data["gamma"] = [_per_cell(s, gamma, model.n_segments, "gamma") for s in view.segments]
    point_data = {}
    n = min(int(n_modes), model.n_dofs - 1)
    if n >= 1:
        freqs, shapes, _ = model.modes(alpha, n, gamma)          # (n, n_rows) without a mesh
        for k, (f, shape) in enumerate(zip(freqs, shapes), start=1):
            nodal = (view.rows_to_nodes @ shape).reshape(-1, 3)
            big = np.unravel_index(np.argmax(np.abs(nodal)), nodal.shape)
            point_data[mode_field_name(k, float(f))] = nodal if nodal[big] >= 0 else -nodal
    return meshio.Mesh(points=view.points, cells=view.blocks, point_data=point_data, cell_data=cell_data)
