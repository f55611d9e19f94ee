"""The structures of ``python -m benchmarks.make.own_cases`` (issue 28): a plate and a frame of solid members as
small tet4 meshes, their scikit-fem model (its own elements and assembly) and the effects added there.

* **plate**: steel, 0.6 x 0.4 x 0.012 m, clamped along x = 0, 15 x 10 x 2 boxes of 6 tetrahedra (1,800 cells,
  528 nodes, 1,551 free DOFs); four segments (the quadrants x < / > 0.3 m, y < / > 0.2 m); six sensors along z
  on the long edges at x = 0.2, 0.4, 0.6 m; the excitation along z at (0.6, 0.1, top).
* **frame**: a steel portal frame of solid members, two columns 0.04 x 0.04 x 0.6 m at x = 0 and x = 0.76 m and a
  beam 0.04 m deep across their tops (0.8 m), boxes of 0.02 m (2,304 cells), feet clamped; four segments (the
  columns, the beam's halves); six sensors (sway x at both column tops, y and z on the beam); the excitation at
  the left column's top along (1, 0.5, 0.3).

The tetrahedra split each box along its main diagonal (Kuhn: conforming between neighbouring boxes), every cell
positively oriented. The mesh goes to ``<name>.vtu`` with 0/1 arrays for the segments' cells (cell data) and the
clamped nodes (point data ``clamp``), the sets :mod:`fe_core.io.mesh_file` reads; ``model.toml`` names them.

scikit-fem assembles the same mesh with its own P1 tetrahedra (``ElementVector(ElementTetP1)``, its
``linear_elasticity`` and a mass form), per segment; the effects are added to its matrices (a point mass on the
node's three DOFs, a spring on one DOF, a patch's stiffness scaled by ``1 + beta``) and its FRF is one direct
complex solve per frequency with scipy: nothing of ``fe_core`` takes part.
"""

from __future__ import annotations

from itertools import permutations
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

E, NU, RHO = 2.1e11, 0.3, 7850.0
ZETA = 0.015   # Rayleigh damping: 1.5 % of critical at the nominal model's modes 1 and 4


def _box_mesh(xs, ys, zs, active) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (n, 3) and tetrahedra (c, 4) of the boxes of the grid ``xs x ys x zs`` where ``active(i, j, k)``."""
    shape = (len(xs), len(ys), len(zs))
    index = np.arange(np.prod(shape)).reshape(shape)
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    tets = []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            for k in range(len(zs) - 1):
                if not active(i, j, k):
                    continue
                for order in permutations(range(3)):
                    step = np.zeros(3, int)
                    corners = [index[i, j, k]]
                    for axis in order:
                        step[axis] = 1
                        corners.append(index[i + step[0], j + step[1], k + step[2]])
                    tets.append(corners)
    tets = np.array(tets)
    used = np.unique(tets)
    renumber = np.full(grid.shape[0], -1)
    renumber[used] = np.arange(used.size)
    nodes, cells = grid[used], renumber[tets]
    a, b, c, d = (nodes[cells[:, m]] for m in range(4))
    negative = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    cells[negative, 1], cells[negative, 2] = cells[negative, 2], cells[negative, 1].copy()
    return nodes, cells


def plate() -> dict:
    xs, ys, zs = np.linspace(0, 0.6, 16), np.linspace(0, 0.4, 11), np.linspace(0, 0.012, 3)
    nodes, cells = _box_mesh(xs, ys, zs, lambda i, j, k: True)
    c = nodes[cells].mean(axis=1)
    segments = {f"q{n + 1}": np.flatnonzero(((c[:, 0] > 0.3) == bx) & ((c[:, 1] > 0.2) == by))
                for n, (bx, by) in enumerate([(False, False), (False, True), (True, False), (True, True)])}
    top = 0.012
    sensors = [(f"z at ({x}, {y})", (x, y, top), (0, 0, 1)) for x in (0.2, 0.4, 0.6) for y in (0.0, 0.4)]
    return {"name": "plate", "nodes": nodes, "cells": cells, "segments": segments,
            "clamp": np.flatnonzero(np.isclose(nodes[:, 0], 0.0)), "sensors": sensors,
            "excitation": ("corner z", (0.6, 0.1, top), (0.0, 0.0, 1.0)), "alpha": [-0.12, 0.1, 0.15, -0.08]}


def frame() -> dict:
    h = 0.02
    xs, ys, zs = np.arange(41) * h, np.arange(3) * h, np.arange(31) * h
    nodes, cells = _box_mesh(xs, ys, zs, lambda i, j, k: i < 2 or i >= 38 or k >= 28)
    c = nodes[cells].mean(axis=1)
    beam = c[:, 2] > 0.56
    segments = {"column_left": np.flatnonzero(~beam & (c[:, 0] < 0.4)),
                "column_right": np.flatnonzero(~beam & (c[:, 0] > 0.4)),
                "beam_left": np.flatnonzero(beam & (c[:, 0] < 0.4)),
                "beam_right": np.flatnonzero(beam & (c[:, 0] > 0.4))}
    sensors = [("left top x", (0.0, 0.02, 0.58), (1, 0, 0)), ("right top x", (0.8, 0.02, 0.58), (1, 0, 0)),
               ("beam 1/4 z", (0.2, 0.02, 0.6), (0, 0, 1)), ("beam 3/4 z", (0.6, 0.02, 0.6), (0, 0, 1)),
               ("beam mid y", (0.4, 0.0, 0.58), (0, 1, 0)), ("left mid y", (0.0, 0.0, 0.3), (0, 1, 0))]
    return {"name": "frame", "nodes": nodes, "cells": cells, "segments": segments,
            "clamp": np.flatnonzero(np.isclose(nodes[:, 2], 0.0)), "sensors": sensors,
            "excitation": ("left top", (0.0, 0.0, 0.6), (1.0, 0.5, 0.3)), "alpha": [0.1, -0.12, -0.1, 0.12]}


def node_at(s: dict, point) -> int:
    return int(np.argmin(np.linalg.norm(s["nodes"] - np.asarray(point, float), axis=1)))


def patch_cells(cells: np.ndarray, centre: int, rings: int = 2) -> np.ndarray:
    """Cells within ``rings`` rings of a node (ring 1: the cells touching it; ring 2: those touching ring 1)."""
    nodes = np.array([centre])
    for _ in range(rings):
        inside = np.flatnonzero(np.any(np.isin(cells, nodes), axis=1))
        nodes = np.unique(cells[inside])
    return inside


# -- scikit-fem ------------------------------------------------------------------------------------------


def skfem_model(s: dict) -> dict:
    """scikit-fem's mesh, basis and matrices: ``K``, ``M`` per segment (in ``s["segments"]`` order) and the
    rest (empty here), the clamped DOFs, the sensors' output rows and the load vector."""
    from skfem import Basis, BilinearForm, ElementTetP1, ElementVector, MeshTet, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = MeshTet(s["nodes"].T.copy(), s["cells"].T.copy())
    element = ElementVector(ElementTetP1())
    basis = Basis(mesh, element)
    stiffness = linear_elasticity(*lame_parameters(E, NU))

    @BilinearForm
    def mass(u, v, w):
        return RHO * dot(u, v)

    def assemble(cells):
        if len(cells) == 0:
            return sp.csr_matrix((basis.N, basis.N)), sp.csr_matrix((basis.N, basis.N))
        sub = Basis(mesh, element, elements=np.asarray(cells))
        return asm(stiffness, sub).tocsr(), asm(mass, sub).tocsr()

    dofs = basis.nodal_dofs  # (3, n_nodes)
    outputs = []
    for _, point, direction in s["sensors"]:
        row = np.zeros(basis.N)
        d = np.asarray(direction, float)
        row[dofs[:, node_at(s, point)]] = d / np.linalg.norm(d)
        outputs.append(row)
    _, point, direction = s["excitation"]
    load = np.zeros(basis.N)
    d = np.asarray(direction, float)
    load[dofs[:, node_at(s, point)]] = d / np.linalg.norm(d)
    return {"mesh": mesh, "basis": basis, "assemble": assemble, "dofs": dofs,
            "segments": [assemble(c) for c in s["segments"].values()],
            "fixed": dofs[:, s["clamp"]].ravel(), "outputs": np.array(outputs), "load": load}


def matrices(fem: dict, alpha, effect: dict | None = None, s: dict | None = None):
    """K and M of scikit-fem's model at ``alpha`` with ``effect`` (``kind`` point_mass / grounded_spring_<x|y|z>
    / patch, ``node``, ``value``) added."""
    K = sum((1 + a) * Ks for a, (Ks, _) in zip(alpha, fem["segments"]))
    M = sum(Ms for _, Ms in fem["segments"])
    if effect is None:
        return K, M
    n = fem["basis"].N
    rows = fem["dofs"][:, effect["node"]]
    if effect["kind"] == "point_mass":
        M = M + sp.csr_matrix((np.full(3, effect["value"]), (rows, rows)), shape=(n, n))
    elif effect["kind"].startswith("grounded_spring"):
        row = rows["xyz".index(effect["kind"][-1])]
        K = K + sp.csr_matrix(([effect["value"]], ([row], [row])), shape=(n, n))
    elif effect["kind"] == "patch":
        cells = patch_cells(s["cells"], effect["node"])
        for a, seg in zip(alpha, s["segments"].values()):
            K = K + effect["value"] * (1 + a) * fem["assemble"](np.intersect1d(seg, cells))[0]
    else:
        raise ValueError(effect["kind"])
    return K.tocsr(), M.tocsr()


def modes_hz(fem: dict, K, M, k: int = 6) -> np.ndarray:
    from skfem import condense

    Kc, Mc, _, _ = condense(K, M, D=fem["fixed"])
    vals = spla.eigsh(Kc, k=k, M=Mc, sigma=0, which="LM", return_eigenvectors=False)
    return np.sort(np.sqrt(np.abs(vals))) / (2 * np.pi)


def rayleigh(fem: dict, s: dict) -> tuple[float, float]:
    """``(a, b)`` giving ZETA at the nominal model's modes 1 and 4."""
    w = 2 * np.pi * modes_hz(fem, *matrices(fem, np.zeros(len(s["segments"]))))
    w1, w4 = w[0], w[3]
    # 6 digits: the eigensolver's start vector moves the last digits between runs; the files stay the same.
    return float(f"{2 * ZETA * w1 * w4 / (w1 + w4):.6g}"), float(f"{2 * ZETA / (w1 + w4):.6g}")


def frf(fem: dict, K, M, damping, freqs_hz) -> np.ndarray:
    """Receptance at the sensors, (p, n_sensors) complex, m/N: one direct complex solve per frequency."""
    from skfem import condense

    a, b = damping
    out = []
    for f in np.asarray(freqs_hz, float):
        w = 2 * np.pi * f
        A = (K - w**2 * M + 1j * w * (a * M + b * K)).tocsc()
        Ac, Fc, _, I = condense(A, fem["load"].astype(complex), D=fem["fixed"])
        u = np.zeros(A.shape[0], complex)
        u[I] = spla.spsolve(sp.csc_matrix(Ac), Fc)
        out.append(fem["outputs"] @ u)
    return np.array(out)


def static_stiffness(fem: dict, K, node: int, axis: int) -> float:
    """1 / compliance of one DOF of the clamped structure, N/m."""
    return row_stiffness(K, fem["fixed"], fem["dofs"][axis, node])


def row_stiffness(K, fixed, row: int) -> float:
    """1 / compliance of DOF ``row`` of ``K`` with the DOFs ``fixed`` clamped, N/m (scikit-fem's condense)."""
    from skfem import condense

    f = np.zeros(K.shape[0])
    f[row] = 1.0
    Kc, fc, _, I = condense(K, f, D=fixed)
    u = np.zeros(K.shape[0])
    u[I] = spla.spsolve(Kc.tocsc(), fc)
    return 1.0 / u[row]


# -- our model file --------------------------------------------------------------------------------------


def write_model(s: dict, out: Path, damping) -> None:
    """``<name>.vtu`` (tetra, the segments' and the clamp's 0/1 arrays) and ``model.toml``."""
    import meshio

    out.mkdir(parents=True, exist_ok=True)
    n_cells = s["cells"].shape[0]
    cell_data = {}
    for name, cells in s["segments"].items():
        flag = np.zeros(n_cells, np.int32)
        flag[cells] = 1
        cell_data[name] = [flag]
    clamp = np.zeros(len(s["nodes"]), np.int32)
    clamp[s["clamp"]] = 1
    meshio.write(out / f"{s['name']}.vtu", meshio.Mesh(s["nodes"], [("tetra", s["cells"])], cell_data=cell_data,
                                                       point_data={"clamp": clamp}))
    lines = [f"# The {s['name']} of issue 28's own cases: tet4, written by python -m benchmarks.make.own_cases.",
             'units = "SI"', f'mesh = "{s["name"]}.vtu"', "", "[damping]", f"a = {float(damping[0])!r}",
             f"b = {float(damping[1])!r}", "", "[[materials]]", f"E = {E!r}", f"nu = {NU!r}", f"rho = {RHO!r}", ""]
    for name in s["segments"]:
        lines += ["[[segments]]", f'set = "{name}"', "bounds = [-0.5, 0.5]", ""]
    lines += ["[[supports]]", 'nodes = "clamp"', 'fix = ["x", "y", "z"]', ""]
    for name, point, direction in s["sensors"]:
        lines += ["[[sensors]]", f'name = "{name}"', f"node = {node_at(s, point)}",
                  f"direction = {[float(v) for v in direction]}", ""]
    name, point, direction = s["excitation"]
    lines += ["[[excitations]]", f'name = "{name}"', f"node = {node_at(s, point)}",
              f"direction = {[float(v) for v in direction]}", ""]
    (out / "model.toml").write_text("\n".join(lines))
