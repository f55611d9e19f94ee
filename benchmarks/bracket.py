"""The L-bracket tet10 example as a bare FE problem (no model file): K, M, a load and outputs.

Shared by ``benchmarks.elements`` and ``benchmarks.solvers``. The mesh is read with
meshio; every volume cell of a supported family is assembled with one material
(steel); the support fixes all three directions of the nodes of a surface group
(default the bolt holes); the load is a unit force in x at the web-top node nearest
the web's free corner region, and the outputs are x, y and z at three web-top and
rib nodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from fe_core.assembly import assemble, free_dof_map
from fe_core.elements import element_family
from fe_core.material import isotropic_elasticity

BRACKET = Path(__file__).resolve().parents[1] / "data" / "examples" / "bracket"
E, NU, RHO = 2.06e11, 0.3, 7850.0
DAMPING = (1e-2, 1e-5)  # Rayleigh a (1/s), b (s)
FREQUENCIES_HZ = np.linspace(200.0, 3000.0, 12)
LOAD_POINT = (0.0, 0.04, 0.12)  # web top, front edge, mid-width
OUTPUT_POINTS = ((0.0, 0.0, 0.12), (0.01, 0.08, 0.12), (0.035, 0.004, 0.035))


@dataclass
class BracketProblem:
    """Free-DOF matrices and the load case of the bracket.

    Attributes
    ----------
    K, M : scipy.sparse.csr_matrix, shape (n_free, n_free)
        N/m and kg.
    F : ndarray, shape (n_free, 1), N
    out_dofs : ndarray, shape (9,), int
        Free-DOF indices of the outputs.
    n_cells, n_dofs : int
        Volume cells and all DOFs (before the support).
    """

    K: sp.csr_matrix
    M: sp.csr_matrix
    F: np.ndarray
    out_dofs: np.ndarray
    n_cells: int
    n_dofs: int


def read(path: Path | str):
    import meshio  # only the benchmarks read meshes here

    return meshio.read(path)


def volume_cells(mesh) -> tuple[str, np.ndarray]:
    """The single volume cell block type and its connectivity, shape (n_cells, NODES)."""
    blocks = [(c.type, c.data) for c in mesh.cells if c.type in ("tetra", "tetra10", "hexahedron")]
    cell_type = blocks[0][0]
    return cell_type, np.concatenate([data for t, data in blocks if t == cell_type])


def element_matrices(points: np.ndarray, cell_type: str, cells: np.ndarray):
    """Element stiffness and mass of every cell, shapes (n_cells, d, d)."""
    family = element_family(cell_type)
    coords = points[cells]
    return family.element_stiffness(coords, isotropic_elasticity(E, NU)), family.element_mass(coords, RHO)


def problem(path: Path | str = BRACKET / "bracket.msh", support: str = "bolt_holes") -> BracketProblem:
    """Assemble the bracket from its mesh file."""
    mesh = read(path)
    cell_type, cells = volume_cells(mesh)
    n = 3 * mesh.points.shape[0]
    dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(cells.shape[0], -1)
    Ke, Me = element_matrices(mesh.points, cell_type, cells)
    K, M = assemble(Ke, dofs, n), assemble(Me, dofs, n)

    members = mesh.cell_sets_dict[support]  # {cell type: indices into cells_dict[type]}
    support_nodes = np.unique(np.concatenate([mesh.cells_dict[t][i].ravel() for t, i in members.items()]))
    fixed = (3 * support_nodes[:, None] + np.arange(3)).ravel()
    free = free_dof_map(n, fixed)
    position = np.full(n, -1)
    position[free] = np.arange(free.size)

    def nearest(point) -> int:
        return int(np.argmin(np.linalg.norm(mesh.points - np.asarray(point), axis=1)))

    F = np.zeros((free.size, 1))
    F[position[3 * nearest(LOAD_POINT)], 0] = 1.0
    out = np.array([position[3 * nearest(p) + c] for p in OUTPUT_POINTS for c in range(3)])
    return BracketProblem(K[free][:, free].tocsr(), M[free][:, free].tocsr(), F, out, cells.shape[0], n)
