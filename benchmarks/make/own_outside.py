"""Effects outside the closure's library on issue 28's own structures (:mod:`benchmarks.make.own_cases`), built in
scikit-fem only (nothing of ``fe_core`` takes part):

* **a non-structural mass layer** on the plate (:func:`mass_layer`): extra density over the cells of a rectangle
  that straddles all four quadrants (segments), a distributed mass with its rotary inertia. The library has point
  masses at nodes and a mass factor per *segment* (``segment_mass``): neither is a mass spread over part of
  several segments.
* **a flexible bolted joint** on the frame (:func:`jointed_frame`): the beam is cut from the left column's top
  (the interface plane z = 0.56 m over the column's 0.04 x 0.04 m section: the interface nodes are doubled, the
  beam's cells take the copies) and the two sides are tied by springs at every interface node pair, soft along
  the normal (z: the joint's rotational flexibility, ``k_rot = k_n I`` of the section) and stiffer in shear. The
  library's stiffness effects scale the element stiffness of a set of cells (patches, cell sets) or tie a node to
  ground: none is a compliant interface between two members, with normal and shear stiffness apart.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from benchmarks.make import own_structures as st

#: The plate's mass layer: the rectangle (x0, x1, y0, y1), m, whose cells (by centroid) carry it.
LAYER_REGION = (0.24, 0.48, 0.08, 0.32)
#: The frame's joint: the interface plane's height, m, the column's x range, m, and the shear / normal stiffness.
JOINT_Z, JOINT_X = 0.56, (0.0, 0.04)
SHEAR_TO_NORMAL = 10.0


def layer_cells(s: dict) -> np.ndarray:
    """The plate's cells whose centroid lies in :data:`LAYER_REGION`."""
    c = s["nodes"][s["cells"]].mean(axis=1)
    x0, x1, y0, y1 = LAYER_REGION
    return np.flatnonzero((c[:, 0] > x0) & (c[:, 0] < x1) & (c[:, 1] > y0) & (c[:, 1] < y1))


def mass_layer(s: dict, fem: dict, mass_kg: float) -> sp.csr_matrix:
    """The layer's mass matrix: scikit-fem's consistent mass of the region's cells scaled to ``mass_kg``."""
    M = fem["assemble"](layer_cells(s))[1]
    return (M * (mass_kg / (float(M.sum()) / 3.0))).tocsr()


def jointed_frame(s: dict) -> tuple[dict, dict, np.ndarray]:
    """The frame with its left joint cut: the structure (interface nodes doubled, the beam's cells on the copies),
    its scikit-fem model and the pairs (original, copy) of node indices, shape (k, 2). Sensors, excitation and
    clamp stay on the original nodes (the copies come after them: ``node_at`` finds the originals)."""
    nodes, cells = s["nodes"], s["cells"].copy()
    on_plane = (np.isclose(nodes[:, 2], JOINT_Z) & (nodes[:, 0] >= JOINT_X[0] - 1e-9)
                & (nodes[:, 0] <= JOINT_X[1] + 1e-9))
    iface = np.flatnonzero(on_plane)
    copy = np.full(len(nodes), -1)
    copy[iface] = len(nodes) + np.arange(iface.size)
    beam = nodes[cells].mean(axis=1)[:, 2] > JOINT_Z
    sub = cells[beam]
    hit = copy[sub] >= 0
    sub[hit] = copy[sub[hit]]
    cells[beam] = sub
    s2 = {**s, "nodes": np.vstack([nodes, nodes[iface]]), "cells": cells}
    return s2, st.skfem_model(s2), np.column_stack([iface, copy[iface]])


def joint_springs(fem: dict, pairs: np.ndarray, k_normal: float) -> sp.csr_matrix:
    """Springs between every (original, copy) pair: ``k_normal`` per node along z, ``SHEAR_TO_NORMAL`` times it
    along x and y."""
    n = fem["basis"].N
    rows, cols, vals = [], [], []
    for axis, k in ((0, SHEAR_TO_NORMAL * k_normal), (1, SHEAR_TO_NORMAL * k_normal), (2, k_normal)):
        a, b = fem["dofs"][axis, pairs[:, 0]], fem["dofs"][axis, pairs[:, 1]]
        rows += [a, b, a, b]
        cols += [a, b, b, a]
        vals += [np.full(a.size, k), np.full(a.size, k), np.full(a.size, -k), np.full(a.size, -k)]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
