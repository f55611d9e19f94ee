"""The tet10 plate of the far-effect cases: a clamped steel plate with a hole and a rib, meshed by gmsh, and its
independent model in scikit-fem (quadratic tetrahedra on the same vertices, straight edges, its own assembly).

Geometry (``PlateSpec``): a plate ``length x width x thickness`` (x, y, z) clamped on its face at x = 0, a round
hole through it, a rib of ``rib_height x rib_thickness`` on its top face along x at ``rib_y``. Segments: the
plate's four quadrants (x below / above ``length / 2``, y below / above ``width / 2``) and the rib. The mesh is
gmsh's second-order tetrahedra (``tetra10``) written as MSH 4.1 with a physical volume per segment and the clamped
face as a physical surface ``clamp``.

scikit-fem's model: the mesh's vertices and corner connectivity as a ``MeshTet``, ``ElementVector(ElementTetP2)``
(its own P2 shape functions on straight-edged tetrahedra: where gmsh put a hole's mid-edge nodes on the circle,
this geometry is the chord's, a small model difference), ``linear_elasticity`` and a mass form assembled per
segment. Its FRF is modal superposition over every mode below ``MODAL_CUTOFF`` times the top line (Rayleigh
damping is diagonal in the modes) plus the static residual of the rest; checked against direct complex solves at a
few lines (``check_frf``). Nothing of ``fe_core`` takes part.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

E, NU, RHO = 2.1e11, 0.3, 7850.0
#: Modes up to this multiple of the top line enter the modal superposition (the rest as a static residual).
MODAL_CUTOFF = 8.0


@dataclass(frozen=True)
class PlateSpec:
    """One plate: geometry (m), mesh size (m), sensors (name, point, direction) and the excitation."""

    name: str = "plate"
    length: float = 0.6
    width: float = 0.4
    thickness: float = 0.01
    hole: tuple = (0.38, 0.2, 0.05)           # x, y, radius
    rib_y: float = 0.1
    rib_height: float = 0.03
    rib_thickness: float = 0.01
    size: float = 0.0125
    sensors: tuple = field(default_factory=tuple)
    excitation: tuple = ("corner z", (0.6, 0.4, 0.01), (0.3, 0.0, 1.0))

    @property
    def segments(self) -> tuple:
        return ("q_root_low", "q_root_high", "q_tip_low", "q_tip_high", "rib")


def default_sensors(s: PlateSpec) -> tuple:
    """Eight sensors along z on the top face, spread over the plate away from the hole."""
    t, L, W = s.thickness, s.length, s.width
    pts = [(0.3 * L, 0.0), (0.6 * L, 0.0), (L, 0.0), (L, 0.5 * W), (0.8 * L, W), (0.45 * L, W), (0.2 * L, 0.75 * W),
           (0.62 * L, 0.35 * W)]
    return tuple((f"z{k + 1}", (x, y, t), (0.0, 0.0, 1.0)) for k, (x, y) in enumerate(pts))


def _segment_of(s: PlateSpec, centre) -> str:
    x, y, z = centre
    if z > s.thickness + 1e-9:
        return "rib"
    return ("q_tip" if x > s.length / 2 else "q_root") + ("_high" if y > s.width / 2 else "_low")


def mesh(s: PlateSpec, out: Path) -> Path:
    """Mesh the plate with gmsh (OpenCASCADE, second order) into ``out`` (MSH 4.1)."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(s.name)
        occ = gmsh.model.occ
        L, W, t = s.length, s.width, s.thickness
        quads = [occ.addBox(x0, y0, 0.0, L / 2, W / 2, t) for x0 in (0.0, L / 2) for y0 in (0.0, W / 2)]
        hx, hy, hr = s.hole
        hole = occ.addCylinder(hx, hy, -0.001, 0.0, 0.0, t + 0.002, hr)
        cut, _ = occ.cut([(3, q) for q in quads], [(3, hole)])
        rib = occ.addBox(0.0, s.rib_y - s.rib_thickness / 2, t, L, s.rib_thickness, s.rib_height)
        occ.fragment(cut + [(3, rib)], [])
        occ.synchronize()
        groups: dict[str, list[int]] = {name: [] for name in s.segments}
        for dim, tag in gmsh.model.getEntities(3):
            groups[_segment_of(s, occ.getCenterOfMass(dim, tag))].append(tag)
        for name in s.segments:
            if not groups[name]:
                raise RuntimeError(f"segment {name!r} has no volume")
            gmsh.model.addPhysicalGroup(3, groups[name], name=name)
        clamp = [tag for dim, tag in gmsh.model.getEntities(2) if gmsh.model.getBoundingBox(dim, tag)[3] < 1e-6]
        gmsh.model.addPhysicalGroup(2, clamp, name="clamp")
        gmsh.option.setNumber("Mesh.MeshSizeMax", s.size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", s.size / 3)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 16)
        gmsh.option.setNumber("Mesh.ElementOrder", 2)
        gmsh.option.setNumber("Mesh.HighOrderOptimize", 1)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 1)
        gmsh.model.mesh.generate(3)
        out.parent.mkdir(parents=True, exist_ok=True)
        gmsh.write(str(out))
    finally:
        gmsh.finalize()
    return out


def read(path: Path) -> dict:
    """The mesh as meshio reads it: nodes (n, 3), tetra10 cells, each segment's cells, the clamped nodes."""
    import meshio

    m = meshio.read(path)
    cells = np.vstack([b.data for b in m.cells if b.type == "tetra10"])
    offsets, segments = 0, {}
    tet_blocks = [(k, b) for k, b in enumerate(m.cells) if b.type == "tetra10"]
    names = {int(v[0]): k for k, v in m.field_data.items()}
    phys = m.cell_data["gmsh:physical"]
    for k, b in tet_blocks:
        name = names[int(phys[k][0])]
        segments.setdefault(name, []).append(np.arange(offsets, offsets + len(b.data)))
        offsets += len(b.data)
    segments = {k: np.concatenate(v) for k, v in segments.items()}
    clamp = np.unique(np.concatenate([b.data.ravel() for k, b in enumerate(m.cells) if b.type.startswith("triangle")
                                      and names[int(phys[k][0])] == "clamp"]))
    return {"nodes": m.points, "cells": cells, "segments": segments, "clamp": clamp}


def vertex_at(g: dict, point) -> int:
    """The vertex node (a tetrahedron's corner) nearest ``point``."""
    corners = np.unique(g["cells"][:, :4])
    d = np.linalg.norm(g["nodes"][corners] - np.asarray(point, float), axis=1)
    return int(corners[np.argmin(d)])


def skfem_model(g: dict, s: PlateSpec) -> dict:
    """scikit-fem's P2 model of the mesh's vertices: matrices per segment (``s.segments`` order), the clamped DOFs,
    ``dofs(node)`` (the three nodal DOFs of a mesh vertex) and ``assemble(cells)``."""
    from skfem import Basis, BilinearForm, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    corners = np.unique(g["cells"][:, :4])
    index = np.full(len(g["nodes"]), -1)
    index[corners] = np.arange(corners.size)
    t = index[g["cells"][:, :4]]
    p = g["nodes"][corners]
    a, b, c, d = (p[t[:, k]] for k in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    t[neg, 1], t[neg, 2] = t[neg, 2], t[neg, 1].copy()
    mesh_ = MeshTet(p.T.copy(), t.T.copy())
    element = ElementVector(ElementTetP2())
    basis = Basis(mesh_, element)
    stiffness = linear_elasticity(*lame_parameters(E, NU))

    @BilinearForm
    def mass(u, v, w):
        return RHO * dot(u, v)

    def assemble(cells):
        sub = Basis(mesh_, element, elements=np.asarray(cells))
        return asm(stiffness, sub).tocsr(), asm(mass, sub).tocsr()

    nodal = basis.nodal_dofs  # (3, n_vertices)

    def dofs(node: int) -> np.ndarray:
        if index[node] < 0:
            raise ValueError(f"node {node} is not a vertex")
        return nodal[:, index[node]]

    clamp_facets = mesh_.facets_satisfying(lambda x: np.abs(x[0]) < 1e-9)
    fixed = basis.get_dofs(clamp_facets).all()
    return {"basis": basis, "assemble": assemble, "dofs": dofs, "N": basis.N, "fixed": np.unique(fixed),
            "segments": [assemble(g["segments"][name]) for name in s.segments], "order": list(s.segments)}


def vector_at(fem: dict, node: int, direction) -> np.ndarray:
    v = np.zeros(fem["N"])
    d = np.asarray(direction, float)
    v[fem["dofs"](node)] = d / np.linalg.norm(d)
    return v


def matrices(fem: dict, alpha, effect: dict | None = None, g: dict | None = None):
    """K and M of scikit-fem's model at ``alpha`` with ``effect`` (``kind`` point_mass / grounded_spring_<x|y|z> /
    patch, ``node``, ``value``) added."""
    K = sum((1 + a) * Ks for a, (Ks, _) in zip(alpha, fem["segments"]))
    M = sum(Ms for _, Ms in fem["segments"])
    if effect is None:
        return K.tocsr(), M.tocsr()
    n = fem["N"]
    rows = fem["dofs"](effect["node"])
    if effect["kind"] == "point_mass":
        M = M + sp.csr_matrix((np.full(3, effect["value"]), (rows, rows)), shape=(n, n))
    elif effect["kind"].startswith("grounded_spring"):
        row = rows["xyz".index(effect["kind"][-1])]
        K = K + sp.csr_matrix(([effect["value"]], ([row], [row])), shape=(n, n))
    elif effect["kind"] == "patch":
        from benchmarks.make.own_structures import patch_cells

        cells = patch_cells(g["cells"], effect["node"], effect.get("rings", 2))
        for a, cells_seg in zip(alpha, [g["segments"][k] for k in fem["order"]]):
            K = K + effect["value"] * (1 + a) * fem["assemble"](np.intersect1d(cells_seg, cells))[0]
    else:
        raise ValueError(effect["kind"])
    return K.tocsr(), M.tocsr()


def _pardiso(A, mtype: int):
    """A factorised ``pypardiso`` solver of ``A`` (real; mtype 2 symmetric positive definite, 11 general)."""
    import pypardiso

    solver = pypardiso.PyPardisoSolver(mtype=mtype)
    A = sp.csr_matrix(A)
    if mtype == 2:
        A = sp.triu(A, format="csr")
    solver.factorize(A)
    return solver, A


def modal_frf(fem: dict, K, M, damping, load, outputs, freqs_hz, cutoff: float = MODAL_CUTOFF):
    """Receptance (p, n_out) by modal superposition: every mode below ``cutoff`` times the top line, Rayleigh
    damping per mode, plus the static residual of the modes left out; and the natural frequencies (Hz) found.
    ARPACK in shift-invert about zero on MKL PARDISO's Cholesky of K (SuperLU on these P2 tetrahedra took minutes)."""
    from skfem import condense

    a, b = damping
    Kc, Mc, _, I = condense(K, M, D=fem["fixed"])
    Kc, Mc = Kc.tocsr(), Mc.tocsr()
    solver, Kt = _pardiso(Kc, 2)
    op = spla.LinearOperator(Kc.shape, matvec=lambda x: solver.solve(Kt, np.asarray(x, float)), dtype=float)
    f_top = cutoff * float(np.max(freqs_hz))
    k = 40
    while True:
        vals, vecs = spla.eigsh(Kc, k=k, M=Mc, sigma=0, which="LM", OPinv=op)
        if np.sqrt(max(vals.max(), 0.0)) / (2 * np.pi) > f_top or k >= Kc.shape[0] - 2:
            break
        k *= 2
    order = np.argsort(vals)
    vals, vecs = vals[order], vecs[:, order]
    F, L = load[I], outputs[:, I]
    static = L @ solver.solve(Kt, F)
    pf = vecs.T @ F                               # (k,)
    pl = L @ vecs                                 # (n_out, k)
    static -= pl @ (pf / vals)                    # what the modes left out add at zero frequency
    w = 2 * np.pi * np.asarray(freqs_hz, float)
    den = vals[None, :] - w[:, None] ** 2 + 1j * w[:, None] * (a + b * vals[None, :])
    H = (pl[None, :, :] * pf[None, None, :] / den[:, None, :]).sum(axis=2) + static[None, :]
    return H, np.sqrt(np.abs(vals)) / (2 * np.pi)


def direct_frf(fem: dict, K, M, damping, load, outputs, freqs_hz):
    """Receptance (p, n_out) by one direct solve per line of the complex system in its real 2n form (PARDISO):
    the check of :func:`modal_frf`."""
    from skfem import condense

    a, b = damping
    Kc, Mc, _, I = condense(K, M, D=fem["fixed"])
    F, L = load[I], outputs[:, I]
    out = []
    for f in np.asarray(freqs_hz, float):
        w = 2 * np.pi * f
        Ar = (Kc - w**2 * Mc).tocsr()
        Ai = (w * (a * Mc + b * Kc)).tocsr()
        A = sp.bmat([[Ar, -Ai], [Ai, Ar]], format="csr")
        solver, At = _pardiso(A, 11)
        x = solver.solve(At, np.concatenate([F, np.zeros_like(F)]))
        u = x[: F.size] + 1j * x[F.size:]
        out.append(L @ u)
    return np.array(out)
