"""The effects the measured structures carry, built in the data's own model (scikit-fem's matrices of the data
mesh), never in the tool's:

* in the tool's library (``fe_core/closure/effects``): a **point mass** on a data vertex's three translations;
  a **mount**, a spring to ground along one axis at a data vertex; a **damaged patch**, the stiffness of the
  data cells lying inside the tool mesh's patch ``node N r2`` (the cells within two rings of node N: the
  library's own patch) scaled by ``1 + beta``;
* outside it: a **mass layer**, non-structural mass spread over the data cells of a box straddling several
  segments (consistent mass, so with its rotary inertia; the library has point masses and whole-segment mass
  factors only); a **flexible joint**, two members cut apart at an interface and tied by distributed springs of
  a compliant layer (normal ``E_j / t_j``, shear ``G_j / t_j`` per unit area): the library scales cells'
  stiffness or ties nodes to the ground, but has no compliant interface between members.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from benchmarks.make.cases import fem_data as fd
from benchmarks.make.cases.solids import corner_centroids


def nodal_matrix(n: int, dofs, values) -> sp.csr_matrix:
    dofs = np.atleast_1d(dofs)
    return sp.csr_matrix((np.broadcast_to(values, dofs.shape).astype(float), (dofs, dofs)), shape=(n, n))


def point_mass(d: dict, vertex: int, mass: float) -> sp.csr_matrix:
    return nodal_matrix(d["basis"].N, d["basis"].nodal_dofs[:, vertex], mass)


def mount(d: dict, vertex: int, axis: int, k: float) -> sp.csr_matrix:
    return nodal_matrix(d["basis"].N, d["basis"].nodal_dofs[axis, vertex], k)


def patch_cells(cells: np.ndarray, centre: int, rings: int = 2) -> np.ndarray:
    """Cells within ``rings`` rings of a node, as the tool's ``patch`` (every node of a cell counts)."""
    nodes = np.array([centre])
    inside = np.zeros(0, int)
    for _ in range(rings):
        inside = np.flatnonzero(np.any(np.isin(cells, nodes), axis=1))
        nodes = np.unique(cells[inside])
    return inside


def patch_centre(nodes: np.ndarray, cells: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Where a patch is: the mean of its cells' corner centroids, m."""
    return corner_centroids(nodes, cells[patch]).mean(axis=0)


def cells_inside(s: dict, model_patch: np.ndarray) -> np.ndarray:
    """The data cells whose corner centroid lies inside one of the tool mesh's cells ``model_patch`` (the same
    cells where both meshes are one: the frame)."""
    if s["data_cells"] is s["model_cells"]:
        return np.asarray(model_patch)
    corners = s["model_nodes"][s["model_cells"][model_patch, :4]]          # (k, 4, 3) straight tets
    c = corner_centroids(s["data_nodes"], s["data_cells"])
    lo, hi = corners.min(axis=(0, 1)) - 1e-9, corners.max(axis=(0, 1)) + 1e-9
    near = np.flatnonzero(np.all((c >= lo) & (c <= hi), axis=1))
    T = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))           # (k, 3, 3) columns: edges from 0
    Tinv = np.linalg.inv(T)
    lam = np.einsum("kij,pkj->pki", Tinv, c[near][:, None, :] - corners[None, :, 0])   # (p, k, 3)
    inside = np.all(lam >= -1e-9, axis=2) & (lam.sum(axis=2) <= 1 + 1e-9)
    return near[inside.any(axis=1)]


def patch_stiffness(s: dict, d: dict, alpha, data_cells: np.ndarray, beta: float) -> sp.csr_matrix:
    """``beta`` times the stiffness (at the case's factors) of the data cells of a patch."""
    seg = d["segment"][data_cells]
    K = sp.csr_matrix((d["basis"].N, d["basis"].N))
    for i in np.unique(seg):
        a = alpha[i] if i >= 0 else 0.0
        K = K + beta * (1.0 + a) * fd.assemble_cells(s, d["basis"], data_cells[seg == i])[0]
    return K.tocsr()


def layer_cells(nodes, cells, region) -> np.ndarray:
    x0, x1, y0, y1, z0, z1 = region
    c = corner_centroids(nodes, cells)
    return np.flatnonzero((c[:, 0] >= x0) & (c[:, 0] <= x1) & (c[:, 1] >= y0) & (c[:, 1] <= y1) & (c[:, 2] >= z0)
                          & (c[:, 2] <= z1))


def mass_layer(s: dict, d: dict, mass: float) -> tuple[sp.csr_matrix, np.ndarray]:
    """The layer's consistent mass, ``mass`` kg over the data cells in ``s["layer"]``, and those cells."""
    cells = layer_cells(s["data_nodes"], s["data_cells"], s["layer"])
    M = fd.assemble_cells(s, d["basis"], cells)[1]
    return (M * (mass / fd.total_mass(d, M))).tocsr(), cells


# -- the flexible joint ---------------------------------------------------------------------------------------
def cut(s: dict) -> tuple[dict, np.ndarray]:
    """The structure with its data mesh cut at the joint's interface: the interface vertices (on the plane, in
    the region) doubled, the cells on the joint's side moved to the copies. Returns it and the copies' originals."""
    j = s["joint"]
    axis, at = j["interface"]
    nodes, cells = s["data_nodes"], s["data_cells"].copy()
    iface = np.flatnonzero(np.isclose(nodes[:, axis], at, atol=1e-9) & j["region"](nodes))
    copy = np.full(len(nodes), -1)
    copy[iface] = len(nodes) + np.arange(iface.size)
    side = j["side"](corner_centroids(nodes, cells))
    sub = cells[side]
    hit = copy[sub] >= 0
    sub[hit] = copy[sub[hit]]
    cells[side] = sub
    s2 = {**s, "data_nodes": np.vstack([nodes, nodes[iface]]), "data_cells": cells}
    s2["support"] = lambda p, f=s["support"], n=len(nodes): np.concatenate([f(p[:n]), np.zeros(len(p) - n, bool)])
    return s2, iface


def _components(basis) -> np.ndarray:
    comp = np.full(basis.N, -1)
    for A in (basis.nodal_dofs, basis.edge_dofs, basis.facet_dofs, basis.interior_dofs):
        A = np.asarray(A)
        for r in range(A.shape[0]):
            comp[A[r]] = r % 3
    return comp


def joint_springs(s2: dict, d2: dict, stiffness_per_area: float, nu_layer: float, area: float) -> tuple:
    """Springs between every pair of coincident DOFs across the cut (same place and component, on the interface):
    normal ``k = stiffness_per_area * area / n``, shear ``k / (2 (1 + nu_layer))`` (a compliant isotropic layer;
    ``n`` the number of DOF places on the interface). Returns the matrix and the number of places."""
    j = s2["joint"]
    axis, at = j["interface"]
    basis = d2["basis"]
    loc = basis.doflocs.T
    comp = _components(basis)
    on = np.flatnonzero(np.isclose(loc[:, axis], at, atol=1e-9) & j["region"](loc))
    keys = {}
    for dof in on:
        keys.setdefault((tuple(np.round(loc[dof], 9)), comp[dof]), []).append(dof)
    pairs = [v for v in keys.values() if len(v) == 2]
    places = len(pairs) // 3
    k_n = stiffness_per_area * area / places
    rows, cols, vals = [], [], []
    for a, b in pairs:
        k = k_n if comp[a] == axis else k_n / (2 * (1 + nu_layer))
        rows += [a, b, a, b]
        cols += [a, b, b, a]
        vals += [k, k, -k, -k]
    n = basis.N
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n)), places
