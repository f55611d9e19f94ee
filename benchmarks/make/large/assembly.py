"""The panel's matrices assembled by scikit-fem, independently of ``fe_core``.

The mesh file is read with meshio; its tet10 cells are straight-sided (``geometry.py``), so scikit-fem's
``ElementVector(ElementTetP2())`` on the corner nodes (a ``MeshTet``) spans the same space as the file's
ten-node cells. scikit-fem numbers its own DOFs (vertices, then edges); every DOF is matched to a node of the
file by its location, and supports, sensors and the excitation are placed the same way, from the model file's
points and the mesh's node sets. Nothing of ``fe_core`` is used: not its reader, element matrices, assembly,
DOF numbering or sensor placement.

The element integrals are exact for straight-sided cells: stiffness with a degree-2 rule (the strains of P2
are linear), mass with degree 4. Each cell's stiffness is scaled by its segment's ``1 + alpha_i`` (a cell
field of the form). The cells are assembled in chunks of :data:`CHUNK` (scikit-fem evaluates every basis
function at every quadrature point of the cells it is given).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: Cells per scikit-fem assembly call (memory ~ CHUNK x 30 basis functions x quadrature points).
CHUNK = 20_000


@dataclass
class Panel:
    """The model of a model file as scikit-fem sees it, on its free DOFs.

    Attributes
    ----------
    K, M : scipy.sparse.csr_matrix, shape (n, n)
        Stiffness (N/m) at the given factors and mass (kg) on the free DOFs.
    outputs : ndarray, shape (n, n_sensors)
        Each sensor's output vector (its unit direction on its node's DOFs).
    load : ndarray, shape (n,), N
        The excitation (unit force along its direction).
    sensor_names : list of str
    excitation_name : str
    n_cells : int
        Tet10 cells.
    n_total : int
        DOFs before the supports (3 per node).
    damping : (float, float)
        Rayleigh ``(a [1/s], b [s])`` of the model file.
    segment_masses : list of float
        Each segment's mass, kg (without an added point mass).
    mass_node : dict or None
        The undeclared point mass, if any: ``node`` (the file's node index), ``xyz_m``, ``mass_kg``.
    """

    K: sp.csr_matrix
    M: sp.csr_matrix
    outputs: np.ndarray
    load: np.ndarray
    sensor_names: list[str]
    excitation_name: str
    n_cells: int
    n_total: int
    damping: tuple[float, float]
    segment_masses: list[float] = field(default_factory=list)
    mass_node: dict | None = None

    @property
    def n_dofs(self) -> int:
        return self.K.shape[0]


def _direction(value) -> np.ndarray:
    if isinstance(value, str):
        return np.eye(3)["xyz".index(value.lower())]
    v = np.asarray(value, float)
    return v / np.linalg.norm(v)


def assemble_panel(spec: dict, mesh_path: Path, alpha: np.ndarray, point_mass=None) -> Panel:
    """Assemble the model file ``spec`` (parsed TOML, SI units, one material) on ``mesh_path``.

    Parameters
    ----------
    spec : dict
        The model file's tables: ``materials`` (one), ``segments`` (cell sets, in order), ``supports``
        (node sets fixed in x, y, z), ``sensors``, ``excitations`` (one, a point and a direction), ``damping``.
    mesh_path : Path
        The gmsh file (tet10 volume groups, triangle6 surface groups).
    alpha : ndarray, shape (n_segments,)
        Stiffness factors: segment i's stiffness times ``1 + alpha_i``.
    point_mass : (array_like of shape (3,), float), optional
        ``(point [m], share)``: a point mass of ``share`` times the panel's mass that the model file does not
        declare, added to scikit-fem's mass matrix on u_x, u_y and u_z of the file's node nearest the point
        (an effect for the closure to find).

    Returns
    -------
    Panel
        With ``mass_node`` (the file's node index, 0-based, and its coordinates) when ``point_mass`` is given.
    """
    import meshio
    import skfem
    from scipy.spatial import cKDTree
    from skfem.helpers import ddot, dot, sym_grad, trace
    from skfem.models.elasticity import lame_parameters

    (material,) = spec["materials"]
    if spec.get("units", "SI") != "SI" or "cells" in material:
        raise ValueError("the independent assembly takes SI units and one material for every cell")
    raw = meshio.read(mesh_path)
    sets = raw.cell_sets_dict
    names = [seg["set"] for seg in spec["segments"]]
    tet = [np.asarray(sets[name]["tetra10"]) for name in names]  # indices into the tetra10 blocks' concatenation
    cells10 = np.vstack([b.data for b in raw.cells if b.type == "tetra10"])
    segment = np.concatenate([np.full(t.size, i) for i, t in enumerate(tet)])
    cells10 = cells10[np.concatenate(tet)]
    if np.unique(np.concatenate(tet)).size != segment.size:
        raise ValueError(f"{mesh_path}: segments overlap")

    # scikit-fem's mesh: the corner nodes (the first four of a ten-node cell in every node order).
    corners = np.unique(cells10[:, :4])
    mesh = skfem.MeshTet(raw.points[corners].T.copy(), np.searchsorted(corners, cells10[:, :4]).T.copy())
    element = skfem.ElementVector(skfem.ElementTetP2())
    dofs = skfem.assembly.Dofs(mesh, element)
    locations = skfem.CellBasis(mesh, element, elements=np.arange(1), dofs=dofs).doflocs.T  # (N, 3)
    N = locations.shape[0]

    # Every scikit-fem DOF at a node of the file, component by component.
    file_nodes = np.unique(cells10)
    tree = cKDTree(raw.points[file_nodes])
    size = float(np.ptp(raw.points, axis=0).max())
    dist, hit = tree.query(locations)
    if dist.max() > 1e-9 * size:
        raise ValueError(f"{mesh_path}: a P2 DOF is {dist.max():.3g} m from every node: the cells are not "
                         "straight-sided (mesh with Mesh.SecondOrderLinear)")
    component = np.empty(N, dtype=int)
    for c in range(3):
        component[dofs.nodal_dofs[c]] = c
        component[dofs.edge_dofs[c]] = c
    node_of = file_nodes[hit]  # file node of each DOF
    dof_at = {(int(n), int(c)): d for d, (n, c) in enumerate(zip(node_of, component))}
    if len(dof_at) != N or N != 3 * file_nodes.size:
        raise ValueError(f"{mesh_path}: scikit-fem's DOFs do not map one to one onto the file's nodes")

    fixed = []
    for support in spec["supports"]:
        nodes = np.unique(np.concatenate([np.asarray(raw.cells[k].data)[idx].ravel()
                                          for k, idx in enumerate(raw.cell_sets[support["nodes"]])
                                          if idx is not None and len(idx)]))
        fixed += [dof_at[(int(n), "xyz".index(c))] for n in nodes for c in support["fix"]]
    free = np.setdiff1d(np.arange(N), fixed)
    position = np.full(N, -1)
    position[free] = np.arange(free.size)

    node_tree = cKDTree(raw.points[file_nodes])
    tolerance = float(spec.get("point_tolerance", 0.01 * size))

    def vector(table: dict) -> np.ndarray:
        d, i = node_tree.query(np.asarray(table["point"], float))
        if d > tolerance:
            raise ValueError(f"{table.get('name')}: no node within {tolerance} m of {table['point']}")
        v = np.zeros(free.size)
        for c, value in enumerate(_direction(table["direction"])):
            if value != 0.0:
                row = position[dof_at[(int(file_nodes[i]), c)]]
                if row < 0:
                    raise ValueError(f"{table.get('name')}: direction {'xyz'[c]} is fixed")
                v[row] = value
        return v

    outputs = np.column_stack([vector(s) for s in spec["sensors"]])
    (excitation,) = spec["excitations"]
    load = vector(excitation)

    lam, mu = lame_parameters(float(material["E"]), float(material["nu"]))
    rho = float(material["rho"])

    @skfem.BilinearForm
    def stiffness_form(u, v, w):  # (1 + alpha of the cell's segment) times linear elasticity
        eps_u, eps_v = sym_grad(u), sym_grad(v)
        return w.factor * (2.0 * mu * ddot(eps_u, eps_v) + lam * trace(eps_u) * trace(eps_v))

    @skfem.BilinearForm
    def mass_form(u, v, w):
        return rho * dot(u, v)

    factor = 1.0 + np.asarray(alpha, float)[segment]  # per cell
    volume = np.zeros(len(cells10))
    K = sp.csr_matrix((N, N))
    M = sp.csr_matrix((N, N))
    for start in range(0, len(cells10), CHUNK):
        chunk = np.arange(start, min(start + CHUNK, len(cells10)))
        kb = skfem.CellBasis(mesh, element, intorder=2, elements=chunk, dofs=dofs, disable_doflocs=True)
        K = K + skfem.asm(stiffness_form, kb, factor=np.repeat(factor[chunk, None], kb.X.shape[1], axis=1))
        del kb
        mb = skfem.CellBasis(mesh, element, intorder=4, elements=chunk, dofs=dofs, disable_doflocs=True)
        M = M + skfem.asm(mass_form, mb)
        volume[chunk] = mb.dx.sum(axis=1)
        del mb
        log.info("scikit-fem: %d of %d cells assembled", chunk[-1] + 1, len(cells10))
    masses = [float(rho * volume[segment == i].sum()) for i in range(len(names))]
    mass_node = None
    if point_mass is not None:
        point, share = point_mass
        kg = float(share) * sum(masses)
        _, i = node_tree.query(np.asarray(point, float))
        node = int(file_nodes[i])
        rows = np.array([dof_at[(node, c)] for c in range(3)])
        if np.any(position[rows] < 0):
            raise ValueError(f"point mass at {list(point)}: node {node} is held by a support")
        M = M + sp.csr_matrix((np.full(3, float(kg)), (rows, rows)), shape=(N, N))
        mass_node = {"node": node, "xyz_m": [float(c) for c in raw.points[node]], "mass_kg": kg,
                     "share_of_mass": float(share)}
    K = K.tocsr()[free][:, free]
    M = M.tocsr()[free][:, free]
    damping = spec.get("damping", {})
    return Panel(K=K, M=M, outputs=outputs, load=load, sensor_names=[s["name"] for s in spec["sensors"]],
                 excitation_name=excitation["name"], n_cells=len(cells10), n_total=N,
                 damping=(float(damping.get("a", 0.0)), float(damping.get("b", 0.0))), segment_masses=masses,
                 mass_node=mass_node)
