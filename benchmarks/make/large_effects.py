"""Data with effects of realistic size, from scikit-fem (issue 28): the closure's joint fit must size them.

    python -m benchmarks.closure_large          # the closure on every case (table)

Two structures, both solved by scikit-fem with scipy's direct solver (one complex solve per frequency), not by
this project's element code, reader or Krylov FRF:

* the steel cantilever of ``data/examples/cantilever_matrices`` (25 x 2 x 2 hex8, 4 segments, model = its
  exported matrices), carrying a point mass of up to 20 % of its 31.4 kg (added to scikit-fem's mass matrix),
  or a spring to ground along y from soft to nearly rigid (added to scikit-fem's stiffness matrix);
* a small clamped steel plate (0.3 x 0.15 x 0.01 m, 10 x 5 x 1 hex8, 3 segments, 6 sensors on u_z): the model
  is this project's own assembly (``build_model``, plain hex8), the data scikit-fem's (``ElementHex1``, 3-point
  Gauss rule, the same element) with a damaged patch: the cells around one top node with their stiffness
  times ``1 + beta`` (scikit-fem's assembly on those cells).

Each case: the truth's factors, 0.5 % multiplicative noise, frequencies at 0.8-1.2 times the effect-carrying
structure's first modes (the cantilever's three y-bending modes, the plate's first four).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from benchmarks.make import matrix_example as mx

NOISE = 0.005
#: The plate: size (m), cells per direction, segment edges along x, Rayleigh damping.
PLATE = dict(size=(0.3, 0.15, 0.01), cells=(10, 5, 1), edges=(0.0, 0.1, 0.2, 0.3), damping=(10.0, 1e-5))
PLATE_ALPHA = np.array([0.1, -0.1, 0.05])
#: The damaged patch's centre on the plate's top face (a patch centre of the library: every second top node).
PATCH_CENTRE = (0.09, 0.06, 0.01)


@functools.lru_cache(maxsize=1)
def _cantilever_fem() -> dict:
    return mx.skfem_model()


def _noisy(Z: np.ndarray, seed: int) -> np.ndarray:
    return np.abs(Z) * (1.0 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))


# -- the cantilever -----------------------------------------------------------------------------------------
def cantilever_case(effect: str, size: float, seed: int = 5, node: int = 208) -> dict:
    """The cantilever with ``effect`` of ``size`` at ``node`` (208: x = 0.68 m, top centre line, in seg4).

    ``effect`` is ``"point_mass"`` (kg, on u_x, u_y, u_z) or ``"grounded_spring_y"`` (N/m, on u_y).
    Returns ``{"model", "freqs", "amplitude", "truth"}``; the model is read from the exported matrices.
    """
    from fe_core.io import read_model
    from flows.config import REPO

    fem = _cantilever_fem()
    if effect == "point_mass":
        fem, node = mx.with_point_mass(fem, fem["mesh"].p[:, node], size)
    elif effect == "grounded_spring_y":
        d = fem["basis"].nodal_dofs[1, node]
        extra = sp.csr_matrix(([float(size)], ([d], [d])), shape=fem["K"][-1].shape)
        fem = {**fem, "K": fem["K"][:-1] + [fem["K"][-1] + extra]}
    else:
        raise ValueError(f"unknown effect {effect!r}")
    freqs = mx.measurement_frequencies(fem)
    u = _noisy(mx.skfem_frf(fem, mx.ALPHA_TRUE, freqs), seed)
    model = read_model(REPO / "data/examples/cantilever_matrices/model.toml")
    return {"model": model, "freqs": freqs, "amplitude": u,
            "truth": {"effect": effect, "location": f"node {node}", "value": float(size),
                      "alpha": mx.ALPHA_TRUE.tolist(), "share_of_mass": float(size) / float(model.total_mass())
                      if effect == "point_mass" else None}}


# -- the plate ----------------------------------------------------------------------------------------------
def plate_model():
    """This project's model of the plate (plain hex8, clamped at x = 0, 6 sensors on u_z, node set ``top``)."""
    from fe_core.benchmark import STEEL
    from fe_core.mesh import Block, mesh_blocks
    from fe_core.model import build_model

    (a, b, c), (nx, ny, nz) = PLATE["size"], PLATE["cells"]
    mesh = mesh_blocks([Block(np.linspace(0, a, nx + 1), np.linspace(0, b, ny + 1), np.linspace(0, c, nz + 1),
                              "plate")])
    cx = mesh.centroids[:, 0]
    edges = PLATE["edges"]
    segments = {f"seg{s + 1}": np.flatnonzero((cx > x0) & (cx < x1)) for s, (x0, x1) in
                enumerate(zip(edges[:-1], edges[1:]))}
    clamped = mesh.nodes_where(x=0.0)
    mesh.add_node_set("clamped", clamped)
    mesh.add_node_set("top", mesh.nodes_where(z=c))
    sensors = [mesh.nearest_node(p) for p in [(x, y, c) for x in (0.15, 0.3) for y in (0.0, 0.09, 0.15)]]
    mesh.add_node_set("sensors", np.array(sensors))
    return build_model(mesh, STEEL, segments, fixed_nodes=clamped, sensor_nodes=sensors, damping=PLATE["damping"],
                       formulation="plain")


def _skfem_plate(model):
    """scikit-fem's mesh, basis and per-cell stiffness assembly of the same plate, with the maps from this
    project's cells and nodes to scikit-fem's."""
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    from fe_core.benchmark import STEEL

    (a, b, c), (nx, ny, nz) = PLATE["size"], PLATE["cells"]
    mesh = skfem.MeshHex.init_tensor(np.linspace(0, a, nx + 1), np.linspace(0, b, ny + 1), np.linspace(0, c, nz + 1))
    element = skfem.ElementVector(skfem.ElementHex1())
    stiffness = linear_elasticity(*lame_parameters(STEEL.E, STEEL.nu))

    @skfem.BilinearForm
    def mass(u, v, w):
        return STEEL.rho * skfem.helpers.dot(u, v)

    centroids = mesh.p[:, mesh.t].mean(axis=1).T  # (n_cells, 3)
    cell_of = np.array([int(np.argmin(np.linalg.norm(centroids - c_, axis=1))) for c_ in model.mesh.centroids])
    node_of = np.array([int(np.argmin(np.linalg.norm(mesh.p.T - p, axis=1))) for p in model.mesh.nodes])

    def K_on(cells):
        return skfem.asm(stiffness, skfem.Basis(mesh, element, elements=np.asarray(cells), intorder=3)).tocsr()

    M = skfem.asm(mass, skfem.Basis(mesh, element, intorder=3)).tocsr()
    basis = skfem.Basis(mesh, element, intorder=3)
    return {"mesh": mesh, "basis": basis, "K_on": K_on, "M": M, "cell_of": cell_of, "node_of": node_of}


def plate_case(beta: float = -0.9, seed: int = 9, rings: int = 1) -> dict:
    """The plate with the patch of ``rings`` rings of cells around :data:`PATCH_CENTRE` at ``1 + beta`` of its
    stiffness (scikit-fem's assembly). Returns ``{"model", "freqs", "amplitude", "truth"}``."""
    model = plate_model()
    fem = _skfem_plate(model)
    from fe_core.closure.effects import build_library

    patch = next(e for e in build_library(model, ["patch"]) if e.kind == "patch")
    centre = model.mesh.nearest_node(PATCH_CENTRE)
    label = f"node {centre} r{rings}"
    cells = patch.bands[label]
    owner = model.cell_segment
    K = fem["K_on"](fem["cell_of"][owner < 0]) if np.any(owner < 0) else 0
    for s in range(model.n_segments):
        mine = np.flatnonzero(owner == s)
        damaged = np.intersect1d(mine, cells)
        K = K + (1 + PLATE_ALPHA[s]) * fem["K_on"](fem["cell_of"][mine])
        if damaged.size:
            K = K + beta * (1 + PLATE_ALPHA[s]) * fem["K_on"](fem["cell_of"][damaged])
    basis, M = fem["basis"], fem["M"]
    clamped = basis.nodal_dofs[:, fem["node_of"][model.mesh.node_sets["clamped"]]].ravel()
    free = np.setdiff1d(np.arange(basis.N), clamped)
    sensors = basis.nodal_dofs[2, fem["node_of"][model.sensor_nodes]]
    load = np.zeros(basis.N)
    load[sensors] = 1.0  # the model's load: unit forces on u_z at the sensors
    Kf, Mf = K[free][:, free].tocsc(), M[free][:, free].tocsc()
    vals = np.sort(spla.eigsh(Kf, k=4, M=Mf, sigma=0, which="LM")[0])
    freqs = np.round(np.concatenate([np.sqrt(v) / (2 * np.pi) * np.asarray(mx.WINDOW) for v in vals]), 1)
    a, b = PLATE["damping"]
    out = []
    for f in freqs:
        w = 2 * np.pi * f
        A = (Kf - w**2 * Mf + 1j * w * (a * Mf + b * Kf)).tocsc()
        x = np.zeros(basis.N, complex)
        x[free] = spla.spsolve(A, load[free].astype(complex))
        out.append(x[sensors])
    u = _noisy(np.array(out), seed)
    return {"model": model, "freqs": freqs, "amplitude": u,
            "truth": {"effect": "patch", "location": label, "value": float(beta), "alpha": PLATE_ALPHA.tolist(),
                      "cells": int(cells.size)}}
