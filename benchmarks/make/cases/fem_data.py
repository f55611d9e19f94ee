"""The measured data's model of a solid structure: scikit-fem's own assembly on the data mesh (P2 tetrahedra on a
gmsh mesh of half the tool's element size, or Q2 hexahedra on the frame's cells), the effects added to its
matrices, and its FRF by modal superposition with static and first-order residual corrections. Nothing of
``fe_core`` takes part.

FRF (receptance, m/N) at the sensors, with Rayleigh damping ``C = a M + b K`` and mass-normalised modes
``phi_k`` (``w_k``) of every mode up to :data:`MODES_UP_TO` times the band's top::

    H(w) = sum_kept (c^T phi_k)(phi_k^T f) / (w_k^2 - w^2 + i w (a + b w_k^2))
           + c^T (R0 + z R1 + z^2 R2 + z^3 R3) f / s,      s = 1 + i w b,  z = (w^2 - i w a) / s

Each mode left out contributes ``phi phi^T / (s (w_k^2 - z))`` exactly, and ``1 / (w_k^2 - z)`` is the series
``sum_j z^j / w_k^(2 j + 2)``: with ``R_j = sum over the modes left out of phi_k phi_k^T / w_k^(2 j + 2)``,
computed without those modes as ``R_j f = (K^-1 M)^j K^-1 P f`` (``P f = f - M Phi Phi^T f`` removes the kept
modes' share of the load, and each iterate is projected again, ``u - Phi Phi^T M u``, so that the kept modes,
amplified by ``(w_cut / w_1)^2`` a step, do not grow back from round-off), they enter with a relative error of
``(|z| / w_k^2)^4``, below ``2^-8 = 0.4 %`` of their (small) part: all of them lie above twice the top. On the
test's bar the modal FRF is 1e-11 to 4e-8 off direct solves. :func:`equilibrium_residual` is the check
of a line: the full solution put back into the dynamic equations.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

#: Modes kept in the superposition: every one below this multiple of the band's top.
MODES_UP_TO = 2.0
CACHE = Path(__file__).resolve().parents[3] / "runs" / "held_out_cache"
#: skfem's hexahedron corner order in VTK's numbering (found from MeshHex.init_tensor: x, y, z bits).
SKFEM_FROM_VTK_HEX = [0, 3, 1, 4, 2, 7, 5, 6]


def _mesh(s: dict):
    from skfem import MeshHex, MeshTet

    nodes, cells = s["data_nodes"], s["data_cells"]
    if cells.shape[1] == 8:
        return MeshHex(nodes.T.copy(), cells[:, SKFEM_FROM_VTK_HEX].T.copy())
    return MeshTet(nodes.T.copy(), cells.T.copy())


def _element(s: dict):
    from skfem import ElementHex2, ElementTetP2, ElementVector

    return ElementVector(ElementHex2() if s["data_cells"].shape[1] == 8 else ElementTetP2())


def forms(material):
    from skfem import BilinearForm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    E, nu, rho = material

    @BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)

    return linear_elasticity(*lame_parameters(E, nu)), mass


def _key(s: dict) -> str:
    h = hashlib.sha256()
    for a in (s["data_nodes"], s["data_cells"]):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr(s["material"]).encode())
    return f"{s['name']}-{h.hexdigest()[:16]}"


def data_model(s: dict, cache: bool = True) -> dict:
    """scikit-fem's model of the data mesh: per-segment K and M (cached in ``runs/held_out_cache``), the held DOFs,
    the sensors' output rows and the load: each at the data mesh's vertex nearest its point, or with ``s["points"]
    == "model"`` at the point of the tool's node nearest it (the data basis's shape functions there)."""
    from skfem import Basis, asm

    mesh, element = _mesh(s), _element(s)
    basis = Basis(mesh, element, intorder=4)
    centroids = s["data_nodes"][s["data_cells"]].mean(axis=1)
    seg = s["segment_of"](centroids)
    file = CACHE / f"{_key(s)}.npz"
    if cache and file.exists():
        z = np.load(file, allow_pickle=False)
        K = [sp.csr_matrix((z[f"K{i}_data"], z[f"K{i}_indices"], z[f"K{i}_indptr"]), shape=(basis.N, basis.N))
             for i in range(len(s["segments"]) + 1)]
        M = [sp.csr_matrix((z[f"M{i}_data"], z[f"M{i}_indices"], z[f"M{i}_indptr"]), shape=(basis.N, basis.N))
             for i in range(len(s["segments"]) + 1)]
    else:
        K, M = [], []
        for i in list(range(len(s["segments"]))) + [-1]:
            Ki, Mi = assemble_cells(s, basis, np.flatnonzero(seg == i))
            K.append(Ki)
            M.append(Mi)
        if cache:
            CACHE.mkdir(parents=True, exist_ok=True)
            arrays = {}
            for name, mats in (("K", K), ("M", M)):
                for i, A in enumerate(mats):
                    arrays.update({f"{name}{i}_data": A.data, f"{name}{i}_indices": A.indices,
                                   f"{name}{i}_indptr": A.indptr})
            np.savez(file, **arrays)
    return _finish(s, basis, K, M, seg)


def assemble_cells(s: dict, basis, cells) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """K and M of the data mesh's ``cells`` alone (full size)."""
    from skfem import Basis, asm

    n = basis.N
    if len(cells) == 0:
        return sp.csr_matrix((n, n)), sp.csr_matrix((n, n))
    stiffness, mass = forms(s["material"])
    sub = Basis(basis.mesh, basis.elem, elements=np.asarray(cells), intorder=4)
    return asm(stiffness, sub).tocsr(), asm(mass, sub).tocsr()


def _finish(s, basis, K, M, seg) -> dict:
    mesh = basis.mesh
    nodes = s["data_nodes"]
    boundary = mesh.boundary_facets()
    held_vertices = s["support"](nodes)
    facets = boundary[np.all(held_vertices[mesh.facets[:, boundary]], axis=0)]
    fixed = basis.get_dofs(facets=facets).all() if facets.size else np.zeros(0, int)
    fixed = np.union1d(fixed, basis.nodal_dofs[:, held_vertices].ravel())

    def row(point, direction):
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        if s.get("points", "vertex") == "model":  # at the tool's node nearest the point (its shape functions there)
            at = s["model_nodes"][int(np.argmin(np.linalg.norm(s["model_nodes"] - np.asarray(point, float), axis=1)))]
            return point_row(basis, at, d), int(np.argmin(np.linalg.norm(nodes - at, axis=1)))
        v = int(np.argmin(np.linalg.norm(nodes - np.asarray(point, float), axis=1)))
        r = np.zeros(basis.N)
        r[basis.nodal_dofs[:, v]] = d
        return r, v

    outputs, sensor_vertices = [], []
    for _, point, direction in s["sensors"]:
        r, v = row(point, direction)
        outputs.append(r)
        sensor_vertices.append(v)
    load, load_vertex = row(*s["excitation"][1:])
    free = np.setdiff1d(np.arange(basis.N), fixed)
    return {"basis": basis, "K": K, "M": M, "segment": seg, "fixed": fixed, "free": free,
            "outputs": np.array(outputs), "load": load, "sensor_vertices": sensor_vertices,
            "load_vertex": load_vertex, "nodes": nodes}


def point_row(basis, point, direction) -> np.ndarray:
    """The basis's row giving the displacement at ``point`` along ``direction`` (a unit force there along it is the
    same vector): the shape functions of the cell holding the point (``probes``, rows component-major)."""
    d = np.asarray(direction, float)
    return (d / np.linalg.norm(d)) @ basis.probes(np.asarray(point, float).reshape(3, 1)).toarray()


def assembled(d: dict, alpha, extra_K=None, extra_M=None) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """K(alpha) = sum (1 + alpha_i) K_i + K_rest (+ extra), M (+ extra), full size."""
    K = sum((1.0 + a) * Ki for a, Ki in zip(alpha, d["K"][:-1])) + d["K"][-1]
    M = sum(d["M"])
    if extra_K is not None:
        K = K + extra_K
    if extra_M is not None:
        M = M + extra_M
    return K.tocsr(), M.tocsr()


def total_mass(d: dict, M=None) -> float:
    """Mass, kg: the x-translation's rigid-body mass (every node's x DOF, held ones too)."""
    M = sum(d["M"]) if M is None else M
    ux = np.zeros(M.shape[0])
    ux[x_dofs(d["basis"])] = 1.0      # the shape functions sum to one: u = 1 along x everywhere
    return float(ux @ (M @ ux))


def x_dofs(basis) -> np.ndarray:
    """Every DOF of the x component (at vertices, and on edges, faces and inside for P2/Q2)."""
    parts = [basis.nodal_dofs, basis.edge_dofs, basis.facet_dofs, basis.interior_dofs]
    return np.concatenate([np.asarray(p)[0].ravel() for p in parts if np.asarray(p).size])


def _locate_mkl() -> None:
    """Find MKL's runtime once and hand it to pypardiso (``PYPARDISO_MKL_RT``): pypardiso otherwise searches
    ``sys.prefix`` with a recursive glob for every solver it makes (2-3 s each)."""
    import ctypes.util
    import glob
    import os
    import sys

    if "PYPARDISO_MKL_RT" in os.environ:
        return
    path = ctypes.util.find_library("mkl_rt") or ctypes.util.find_library("mkl_rt.1")
    if path is None:
        found = glob.glob(f"{sys.prefix}/[Ll]ib*/**/*mkl_rt*", recursive=True)
        path = sorted(found, key=len)[0] if found else None
    if path is not None:
        os.environ["PYPARDISO_MKL_RT"] = path


class Factor:
    """PARDISO's factorisation of a real sparse matrix, as a solve."""

    def __init__(self, A):
        import pypardiso

        _locate_mkl()
        self.A = sp.csr_matrix(A)
        self.solver = pypardiso.PyPardisoSolver(mtype=11)
        self.solver.factorize(self.A)

    def __call__(self, b) -> np.ndarray:
        return self.solver.solve(self.A, np.ascontiguousarray(b, dtype=float))

    def free(self) -> None:
        self.solver.free_memory(everything=True)


def condensed(K, M, free):
    return K[free][:, free].tocsr(), M[free][:, free].tocsr()


def modes(Kc, Mc, top_hz: float, factor: Factor | None = None, start: int = 24):
    """Every mode below ``top_hz`` (at least ``start``): (frequencies Hz ascending, mass-normalised shapes)."""
    factor = factor or Factor(Kc)
    op = spla.LinearOperator(Kc.shape, matvec=factor, dtype=float)
    k = start
    while True:
        k = min(k, Kc.shape[0] - 2)
        v0 = np.ones(Kc.shape[0])  # a fixed start vector: the same modes every run
        vals, vecs = spla.eigsh(Kc, k=k, M=Mc, sigma=0.0, OPinv=op, which="LM", v0=v0)   # tol: machine eps
        order = np.argsort(vals)
        vals, vecs = vals[order], vecs[:, order]
        f = np.sqrt(np.abs(vals)) / (2 * np.pi)
        if f[-1] >= top_hz or k >= Kc.shape[0] - 2:
            keep = f <= top_hz
            keep[:start] = True
            vecs = vecs[:, keep] / np.sqrt(np.einsum("ij,ij->j", vecs[:, keep], Mc @ vecs[:, keep]))
            return f[keep], vecs
        k = int(k * 1.6) + 4


def spectral(Kc, Mc, outputs, load, top_hz: float) -> dict:
    """What the modal FRF needs (module docstring): every mode up to ``top_hz`` and the residual terms;
    ``outputs`` (n_sensors, n_free), ``load`` (n_free,)."""
    factor = Factor(Kc)
    try:
        f_k, phi = modes(Kc, Mc, top_hz, factor)
        def left_out(v):
            return v - phi @ (phi.T @ (Mc @ v))

        u = [left_out(factor(load - Mc @ (phi @ (phi.T @ load))))]
        for _ in range(3):
            u.append(left_out(factor(Mc @ u[-1])))
    finally:
        factor.free()
    w_k2 = (2 * np.pi * f_k) ** 2
    cphi = outputs @ phi                     # (n_s, k)
    phif = phi.T @ load                      # (k,)
    r = np.array([outputs @ uj for uj in u])   # (4, n_s): R_j f at the sensors
    return {"f": f_k, "cphi": cphi, "phif": phif, "r": r, "top_hz": top_hz, "phi": phi, "u": u}


def modal_frf(sp_: dict, damping, freqs_hz) -> np.ndarray:
    """Receptance (p, n_sensors), complex, m/N, of :func:`spectral`'s modes and residuals."""
    w_k2 = (2 * np.pi * sp_["f"]) ** 2
    a, b = damping
    w = 2 * np.pi * np.asarray(freqs_hz, float)
    if w.size and w.max() > 2 * np.pi * sp_["top_hz"] / 2:
        raise ValueError(f"lines up to {w.max() / 2 / np.pi:.1f} Hz: the modes reach {sp_['top_hz']:.1f} Hz only")
    den = w_k2[None, :] - w[:, None] ** 2 + 1j * w[:, None] * (a + b * w_k2[None, :])
    s = 1 + 1j * w * b
    z = (w**2 - 1j * w * a) / s
    left_out = (z[:, None] ** np.arange(4)[None, :]) @ sp_["r"] / s[:, None]
    return (sp_["phif"][None, :] / den) @ sp_["cphi"].T + left_out


def equilibrium_residual(sp_: dict, Kc, Mc, load, damping, f_hz: float) -> float:
    """The check of a line: the modal solution's full displacement ``u`` put back into the dynamic equations,
    ``|(K - w^2 M + i w C) u - f| / |K u|`` (2-norms): round-off and the series' truncation, nothing else."""
    a, b = damping
    w = 2 * np.pi * f_hz
    w_k2 = (2 * np.pi * sp_["f"]) ** 2
    s = 1 + 1j * w * b
    z = (w**2 - 1j * w * a) / s
    u = sp_["phi"] @ (sp_["phif"] / (w_k2 - w**2 + 1j * w * (a + b * w_k2)))
    u = u + sum(z**j * uj for j, uj in enumerate(sp_["u"])) / s
    Ku = Kc @ u
    r = (1 + 1j * w * b) * Ku - (w**2 - 1j * w * a) * (Mc @ u) - load
    return float(np.linalg.norm(r) / np.linalg.norm(Ku))


def rayleigh(f1_hz: float, f2_hz: float, zeta: float) -> tuple[float, float]:
    """Rayleigh ``(a, b)`` giving ``zeta`` at two frequencies (6 digits: written to the model file)."""
    w1, w2 = 2 * np.pi * f1_hz, 2 * np.pi * f2_hz
    return float(f"{2 * zeta * w1 * w2 / (w1 + w2):.6g}"), float(f"{2 * zeta / (w1 + w2):.6g}")


def static_compliance(Kc, free_index, rows) -> np.ndarray:
    """Static compliance (m/N) of each free-DOF row in ``rows`` of the held structure: ``e^T K^-1 e``."""
    factor = Factor(Kc)
    try:
        out = []
        for r in rows:
            e = np.zeros(Kc.shape[0])
            e[free_index[r]] = 1.0
            out.append(float(factor(e)[free_index[r]]))
    finally:
        factor.free()
    return np.array(out)
