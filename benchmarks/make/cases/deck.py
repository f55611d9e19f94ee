"""The shell deck of the held-out cases: a cantilevered aluminium C-channel of S8R shells, a CalculiX deck.

The channel runs along x (0.8 m): its web in the plane y = 0 (0.10 m high), its flanges in z = 0 and z = 0.10 m
(0.04 m wide), 2.5 mm thick; every node at x = 0 is held (``*BOUNDARY CLAMP, 1, 6``). Six segments (``*ELSET``,
each with its own ``*SHELL SECTION``): the web, the bottom and the top flange, each split at x = 0.4 m.

The tool's model is ``channel.inp`` (``MODEL_MESH``: 32 cells along x, 4 up the web, 2 across each flange) with
``model.toml`` (``solver = "calculix"``, route A). The measured data come from ccx's stiffness and mass matrices
(``*FREQUENCY, SOLVER=MATRIXSTORAGE``) of the same channel meshed **twice as finely** (``DATA_MESH``; every model
node is a node there), with the case's factors on the segments' moduli and the effect written into the deck by
ccx's own cards: a point mass (``*ELEMENT, TYPE=MASS``), a mount (``SPRING1`` to ground), a mass layer (the
region's density raised through its own materials). The matrices are read as they are (``.sti``, ``.mas``,
``.dof``); a shell node's displacement is the mean of its expanded rows and a point load is shared equally
among them (what ccx reports and does; docs/solver-decks.md); the FRF is :func:`fem_data.modal_frf`'s.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

L, H, B, T = 0.8, 0.10, 0.04, 0.0025
E, NU, RHO = 7.0e10, 0.33, 2700.0
MODEL_MESH, DATA_MESH = (32, 4, 2), (64, 8, 4)     # cells along x, up the web, across a flange
SEGMENTS = ["WEB_ROOT", "WEB_TIP", "BOTTOM_ROOT", "BOTTOM_TIP", "TOP_ROOT", "TOP_TIP"]
SENSORS = [("tip web y", (0.8, 0.0, 0.05), (0.0, 1.0, 0.0)), ("tip top z", (0.8, 0.04, 0.1), (0.0, 0.0, 1.0)),
           ("tip bottom z", (0.8, 0.04, 0.0), (0.0, 0.0, 1.0)), ("web y at 0.4", (0.4, 0.0, 0.05), (0.0, 1.0, 0.0)),
           ("top z at 0.6", (0.6, 0.04, 0.1), (0.0, 0.0, 1.0)), ("bottom z at 0.3", (0.3, 0.04, 0.0), (0.0, 0.0, 1.0)),
           ("web y at 0.6 low", (0.6, 0.0, 0.025), (0.0, 1.0, 0.0)), ("web y at 0.2 high", (0.2, 0.0, 0.075),
                                                                      (0.0, 1.0, 0.0))]
EXCITATION = ("hammer", (0.775, 0.02, 0.1), (0.0, 0.6, -0.8))
ZETA = 0.012


def _plates():
    """(name, point(u, v) in m, segment of (u, v)): the web, the bottom and the top flange."""
    return [("web", lambda u, v: (L * u, 0.0, H * v), "WEB"), ("bottom", lambda u, v: (L * u, B * v, 0.0), "BOTTOM"),
            ("top", lambda u, v: (L * u, B * v, H), "TOP")]


def mesh(cells=MODEL_MESH) -> tuple[dict, list, dict]:
    """({(x, y, z) rounded: node id}, [(element nodes (8,), segment, centroid)], {id: (x, y, z)})."""
    nx, nw, nf = cells
    ids, coords, elements = {}, {}, []

    def node(p):
        key = tuple(round(c, 9) for c in p)
        if key not in ids:
            ids[key] = len(ids) + 1
            coords[ids[key]] = key
        return ids[key]

    for name, at, seg in _plates():
        nv = nw if name == "web" else nf
        for j in range(nv):
            for i in range(nx):
                u0, u1, v0, v1 = i / nx, (i + 1) / nx, j / nv, (j + 1) / nv
                um, vm = (u0 + u1) / 2, (v0 + v1) / 2
                corners = [at(u0, v0), at(u1, v0), at(u1, v1), at(u0, v1), at(um, v0), at(u1, vm), at(um, v1),
                           at(u0, vm)]
                part = "ROOT" if um < 0.5 else "TIP"
                elements.append(([node(p) for p in corners], f"{seg}_{part}", np.mean(corners[:4], axis=0)))
    return ids, elements, coords


def cards(cells=MODEL_MESH, factors=None, effect: dict | None = None) -> str:
    """The deck's model cards: nominal moduli (the model) or ``factors`` on the segments' moduli, and an effect
    (``point_mass``: ``node``, ``value`` kg; ``grounded_spring_<x|y|z>``: ``node``, ``value`` N/m;
    ``mass_layer``: ``region`` (x0, x1, y0, y1, z0, z1), ``factor`` on the density there)."""
    ids, elements, coords = mesh(cells)
    out = ["** a cantilevered aluminium C-channel of S8R shells (benchmarks/make/cases/deck.py)", "*NODE"]
    out += [f"{i}, {x:.9g}, {y:.9g}, {z:.9g}" for i, (x, y, z) in coords.items()]
    out.append("*ELEMENT, TYPE=S8R, ELSET=CHANNEL")
    out += [f"{e + 1}, " + ", ".join(map(str, n)) for e, (n, _, _) in enumerate(elements)]
    layer = None
    if effect and effect["kind"] == "mass_layer":
        x0, x1, y0, y1, z0, z1 = effect["region"]
        layer = [x0 <= c[0] <= x1 and y0 <= c[1] <= y1 and z0 <= c[2] <= z1 for _, _, c in elements]
    sets = {}
    for e, (_, seg, _) in enumerate(elements):
        sets.setdefault(seg + ("_LAYER" if layer and layer[e] else ""), []).append(e + 1)
    for name in sorted(sets, key=lambda n: (SEGMENTS.index(n.replace("_LAYER", "")), n)):
        out.append(f"*ELSET, ELSET={name}")
        out += [", ".join(map(str, sets[name][k:k + 12])) for k in range(0, len(sets[name]), 12)]
    clamp = [i for (x, _, _), i in ids.items() if abs(x) < 1e-12]
    out.append("*NSET, NSET=CLAMP")
    out += [", ".join(map(str, clamp[k:k + 12])) for k in range(0, len(clamp), 12)]
    if factors is None:
        out += ["*MATERIAL, NAME=ALU", "*ELASTIC", f"{E!r}, {NU}", "*DENSITY", f"{RHO!r}"]
    for name in sets:
        seg = name.replace("_LAYER", "")
        f = 0.0 if factors is None else factors[SEGMENTS.index(seg)]
        rho = RHO * (effect["factor"] if name.endswith("_LAYER") else 1.0)
        material = "ALU" if factors is None else f"ALU_{name}"
        if factors is not None:
            out += [f"*MATERIAL, NAME={material}", "*ELASTIC", f"{float(E * (1 + f))!r}, {NU}", "*DENSITY", f"{float(rho)!r}"]
        out += [f"*SHELL SECTION, ELSET={name}, MATERIAL={material}", f"{T}"]
    n_el = len(elements)
    if effect and effect["kind"] == "point_mass":
        out += ["*ELEMENT, TYPE=MASS, ELSET=ADDED_MASS", f"{n_el + 1}, {effect['node']}",
                "*MASS, ELSET=ADDED_MASS", f"{float(effect['value'])!r}"]
    elif effect and effect["kind"].startswith("grounded_spring"):
        d = "xyz".index(effect["kind"][-1]) + 1
        out += ["*ELEMENT, TYPE=SPRING1, ELSET=MOUNT", f"{n_el + 1}, {effect['node']}", "*SPRING, ELSET=MOUNT",
                f"{d}", f"{float(effect['value'])!r}"]
    out += ["*BOUNDARY", "CLAMP, 1, 6"]
    return "\n".join(out) + "\n"


MODEL_TOML = """# A cantilevered aluminium C-channel of S8R shells, a CalculiX deck (route A).
# Written by python -m benchmarks.make.cases (issue 40's held-out cases; docs/results/held-out.md).
units = "SI"
solver = "calculix"
deck = "channel.inp"
solver_timeout = 300.0

[damping]
a = {a!r}
b = {b!r}
{segments}{sensors}
[[excitations]]
name = "{exc}"
point = {exc_point}
direction = {exc_dir}
"""


def write_model(folder: Path, damping) -> dict:
    """``channel.inp`` (the model mesh, nominal) and ``model.toml``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "channel.inp").write_text(cards(MODEL_MESH) + "*STEP\n*FREQUENCY\n10\n*END STEP\n")
    segs = "".join(f'\n[[segments]]\nset = "{s}"\nbounds = [-0.5, 0.5]\n' for s in SEGMENTS)
    sens = "".join(f'\n[[sensors]]\nname = "{n}"\npoint = {list(map(float, p))}\ndirection = {list(map(float, d))}\n'
                   for n, p, d in SENSORS)
    (folder / "model.toml").write_text(MODEL_TOML.format(
        a=damping[0], b=damping[1], segments=segs, sensors=sens, exc=EXCITATION[0],
        exc_point=list(map(float, EXCITATION[1])), exc_dir=list(map(float, EXCITATION[2]))))
    ids, elements, _ = mesh(MODEL_MESH)
    return {"model_nodes": len(ids), "model_cells": len(elements), "cell_type": "S8R"}


def matrices(factors, effect=None, cells=DATA_MESH, timeout: float = 1800.0):
    """ccx's K and M of the deck (``cards``), with the output rows of the sensors and the load, and the node
    table: ``(K, M, outputs (n_s, n), load (n,), labels (n, 2), coords {id: xyz})``."""
    from fe_core.io.calculix import run_ccx
    from fe_core.io.calculix.results import read_storage

    text = cards(cells, factors, effect)
    with tempfile.TemporaryDirectory(prefix="held-out-deck-") as tmp:
        (Path(tmp) / "deck.inp").write_text(text + "*STEP\n*FREQUENCY, SOLVER=MATRIXSTORAGE\n*END STEP\n")
        run_ccx(tmp, "deck", timeout, expect=(".sti", ".mas", ".dof"))
        K, M, labels = read_storage(tmp, "deck")
    ids, _, coords = mesh(cells)

    def row(point, direction):
        node = ids[tuple(round(c, 9) for c in point)]
        r = np.zeros(labels.shape[0])
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        for c in range(3):
            rows = np.flatnonzero((labels[:, 0] == node) & (labels[:, 1] == c + 1))
            if d[c] != 0.0:
                if rows.size == 0:
                    raise ValueError(f"node {node} has no rows along {'xyz'[c]} in ccx's matrices")
                r[rows] += d[c] / rows.size
        return r

    outputs = np.array([row(p, d) for _, p, d in SENSORS])
    load = row(*EXCITATION[1:])
    return K.tocsr(), M.tocsr(), outputs, load, labels, coords


def node_of(point, cells=MODEL_MESH) -> int:
    return mesh(cells)[0][tuple(round(c, 9) for c in point)]


def region_cells(region, cells=MODEL_MESH) -> int:
    x0, x1, y0, y1, z0, z1 = region
    return sum(x0 <= c[0] <= x1 and y0 <= c[1] <= y1 and z0 <= c[2] <= z1 for _, _, c in mesh(cells)[1])
