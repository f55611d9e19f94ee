"""Issue 28's own cases: three structures that are not the three-plate benchmark, each measured (by scikit-fem,
not by ``fe_core``) with an effect its model file does not declare, at 2 %, 5 % and 10 %.

    python -m benchmarks.make.own_cases      # data/cases/own_structures/: models, measured CSVs, truth.json

Structures (``data/cases/own_structures/README.md``):

* ``cantilever``: ``data/examples/cantilever_matrices/model.toml`` (scikit-fem's hexahedra exported as matrices;
  ``benchmarks.make.matrix_example`` builds it again here and adds the effect to its matrices);
* ``plate`` and ``frame``: tet4 meshes (:mod:`benchmarks.make.own_structures`), ``data/cases/own_structures/<name>/``.

Sizes: a point mass of s of the structure's mass; a mount (a spring to ground along one axis) of s of the
clamped structure's static stiffness at that node and axis; a damaged patch (the cells within 2 rings of a node,
the closure's ``patch ... r2``) whose stiffness is lowered by ``beta = -s V_seg / V_patch``, i.e. the segment holding
most of the patch (what the model updates) loses s of its volume-weighted stiffness, concentrated in the patch. Measured: scikit-fem's direct FRF of the structure with the effect, at the
truth's alpha, at 0.8-1.2 times (9 lines) each of the first four modes of the structure with the effect, windows
of close modes merged into one evenly stepped band (:func:`lines`; the cantilever: its first three bending modes
in y, as ``matrix_example``), 0.5 % multiplicative noise.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.make import own_structures as st

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "data" / "cases" / "own_structures"
NOISE = 0.005
WINDOW = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2)
CANTILEVER_MODEL = "data/examples/cantilever_matrices/model.toml"

#: (case, structure, kind, where (a point, m), share s, seed). Every kind at every size at least once (except
#: a patch on the cantilever, a matrices model without element matrices: the closure cannot name a patch there).
CASES = [
    ("cantilever-mass-2%", "cantilever", "point_mass", (0.52, 0.0, 0.05), 0.02, 101),
    ("cantilever-mount-5%", "cantilever", "grounded_spring_y", (0.6, 0.04, 0.0), 0.05, 102),
    ("cantilever-mass-10%", "cantilever", "point_mass", (0.32, 0.08, 0.025), 0.10, 103),
    ("plate-patch-2%", "plate", "patch", (0.16, 0.12, 0.012), 0.02, 201),
    ("plate-mass-5%", "plate", "point_mass", (0.44, 0.28, 0.012), 0.05, 202),
    ("plate-mount-10%", "plate", "grounded_spring_z", (0.52, 0.32, 0.0), 0.10, 203),
    ("frame-mount-2%", "frame", "grounded_spring_x", (0.78, 0.02, 0.4), 0.02, 301),
    ("frame-patch-5%", "frame", "patch", (0.3, 0.02, 0.58), 0.05, 302),
    ("frame-mass-10%", "frame", "point_mass", (0.0, 0.04, 0.3), 0.10, 303),
    ("plate-patch-10%", "plate", "patch", (0.42, 0.2, 0.012), 0.10, 204),
    ("frame-patch-10%", "frame", "patch", (0.02, 0.02, 0.16), 0.10, 304),
]
#: Cases the closure must not call ``explained``: (case, structure, kind, share or size, seed, expected verdict).
#: Clean data (the truth's alpha, no effect) must give ``noise``; an effect outside the library
#: (:mod:`benchmarks.make.own_outside`) anything but ``explained``. ``mass_layer``: s of the plate's mass spread
#: over a rectangle straddling its four quadrants; ``joint``: the frame's left beam-column joint cut and tied by
#: springs of this normal stiffness per interface node (N/m; shear 10 times stiffer).
CONTROL_CASES = [
    ("plate-clean", "plate", "none", 0.0, 205, "noise"),
    ("frame-clean", "frame", "none", 0.0, 305, "noise"),
    ("plate-layer-10%", "plate", "mass_layer", 0.10, 206, "not explained"),
    ("frame-joint", "frame", "joint", 2e8, 306, "not explained"),
]


def _cantilever() -> dict:
    """The cantilever as ``own_structures`` models are: nodes, K/M per segment + rest, its own FRF."""
    from benchmarks.make import matrix_example as mx

    fem = mx.skfem_model()
    s = {"name": "cantilever", "nodes": fem["mesh"].p.T, "alpha": mx.ALPHA_TRUE.tolist(), "model": CANTILEVER_MODEL,
         "damping": mx.DAMPING}
    return s, fem


def _cantilever_case(s, fem, kind, node, value):
    """scikit-fem's FRF of the cantilever with the effect (added to the remainder's matrices) and its lines."""
    import scipy.sparse as sp

    from benchmarks.make import matrix_example as mx

    n = fem["basis"].N
    rows = fem["basis"].nodal_dofs[:, node]
    if kind == "point_mass":
        extra = sp.csr_matrix((np.full(3, value), (rows, rows)), shape=(n, n))
        fem = {**fem, "M": fem["M"][:-1] + [fem["M"][-1] + extra]}
    else:
        row = rows["xyz".index(kind[-1])]
        extra = sp.csr_matrix(([value], ([row], [row])), shape=(n, n))
        fem = {**fem, "K": fem["K"][:-1] + [fem["K"][-1] + extra]}
    freqs = mx.measurement_frequencies(fem)
    return mx.skfem_frf(fem, mx.ALPHA_TRUE, freqs), freqs


def _control_case(s, fem, kind, size):
    """A control case's lines, scikit-fem FRF and truth entry: no effect, or one outside the library."""
    from benchmarks.make import own_outside as out

    K, M = st.matrices(fem, s["alpha"])
    if kind == "none":
        entry = {"location": None, "node": None, "share": 0.0, "value": 0.0, "xyz_m": None,
                 "description": "no effect"}
    elif kind == "mass_layer":
        mass = size * float(M.sum()) / 3.0
        M = M + out.mass_layer(s, fem, mass)
        x0, x1, y0, y1 = out.LAYER_REGION
        entry = {"location": f"x {x0}-{x1} m, y {y0}-{y1} m", "node": None, "share": size, "value": mass,
                 "xyz_m": [(x0 + x1) / 2, (y0 + y1) / 2, 0.006], "cells": int(out.layer_cells(s).size),
                 "description": f"a non-structural mass layer of {mass:.6g} kg over x {x0}-{x1} m, y {y0}-{y1} m"}
    elif kind == "joint":
        s2, fem2, pairs = out.jointed_frame(s)
        K, M = st.matrices(fem2, s["alpha"])
        K = (K + out.joint_springs(fem2, pairs, size)).tocsr()
        freqs = lines(st.modes_hz(fem2, K, M, 4))
        entry = {"location": f"left joint, z = {out.JOINT_Z} m", "node": None, "share": None, "value": size,
                 "xyz_m": [0.02, 0.02, out.JOINT_Z], "interface_nodes": [int(n) for n in pairs[:, 0]],
                 "description": f"the left beam-column joint tied by springs of {size:.3g} N/m per node along z "
                                f"({out.SHEAR_TO_NORMAL:g} times that in shear) at {len(pairs)} interface nodes"}
        return freqs, st.frf(fem2, K, M, s["damping"], freqs), entry
    else:
        raise ValueError(kind)
    freqs = lines(st.modes_hz(fem, K, M, 4))
    return freqs, st.frf(fem, K, M, s["damping"], freqs), entry


def lines(modes_hz) -> np.ndarray:
    """0.8-1.2 times each mode in steps of 0.05 (``WINDOW``); windows that overlap (close modes) become one
    evenly stepped band at the lower mode's step, so every band has an even step (the closure estimates the noise
    from second differences along evenly stepped bands: ``fe_core.inference.residual.frequency_bands``)."""
    bands = []
    for f in np.sort(np.asarray(modes_hz, float)):
        lo, hi, step = WINDOW[0] * f, WINDOW[-1] * f, (WINDOW[1] - WINDOW[0]) * f
        if bands and lo <= bands[-1][1]:
            bands[-1][1] = max(bands[-1][1], hi)
        else:
            bands.append([lo, hi, step])
    return np.concatenate([np.round(lo + step * np.arange(round((hi - lo) / step) + 1), 1) for lo, hi, step in bands])


def _size(kind, share, s, fem, node) -> float:
    """The effect's value for a share s (module docstring)."""
    if s["name"] == "cantilever":
        K = sum((1 + a) * Ki for a, Ki in zip(s["alpha"], fem["K"][:-1])) + fem["K"][-1]
        M = sum(fem["M"])
        dof = {"dofs": fem["basis"].nodal_dofs, "fixed": fem["fixed"]}
    else:
        K, M = st.matrices(fem, s["alpha"])
        dof = fem
    if kind == "point_mass":
        return share * float(M.sum()) / 3.0  # each translation's mass matrix sums to the structure's mass
    if kind.startswith("grounded_spring"):
        return share * st.static_stiffness(dof, K, node, "xyz".index(kind[-1]))
    cells = st.patch_cells(s["cells"], node)
    volume = _volumes(s["nodes"], s["cells"])
    segment = max(s["segments"].values(), key=lambda seg: np.intersect1d(seg, cells).size)
    beta = -share * float(volume[segment].sum()) / float(volume[cells].sum())
    if beta < -0.9:
        raise ValueError(f"patch at node {node}: beta {beta:.3g} < -0.9; a larger patch or a smaller share")
    return beta


def _volumes(nodes, cells) -> np.ndarray:
    a, b, c, d = (nodes[cells[:, m]] for m in range(4))
    return np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0


def structure_size(nodes) -> float:
    """The structure's size for location errors: its bounding box's largest side, m."""
    return float(np.ptp(np.asarray(nodes), axis=0).max())


def main() -> int:
    from tasks.io.measured import MeasuredFRF, write_measured

    OUT.mkdir(parents=True, exist_ok=True)
    built = {"cantilever": _cantilever()}
    for make in (st.plate, st.frame):
        s = make()
        fem = st.skfem_model(s)
        s["damping"] = st.rayleigh(fem, s)
        s["model"] = f"data/cases/own_structures/{s['name']}/model.toml"
        st.write_model(s, OUT / s["name"], s["damping"])
        built[s["name"]] = (s, fem)
    truth = {"noise": NOISE, "structures": {}, "cases": {}}
    for name, (s, fem) in built.items():
        entry = {"model": s["model"], "alpha": [float(a) for a in s["alpha"]], "size_m": structure_size(s["nodes"]),
                 "nodes": int(len(s["nodes"]))}
        if name != "cantilever":
            entry["mass_kg"] = float(sum(Ms for _, Ms in fem["segments"]).sum()) / 3.0
            entry["damping"] = [float(v) for v in s["damping"]]
        truth["structures"][name] = entry
    for case, name, kind, point, share, seed in CASES:
        s, fem = built[name]
        node = int(np.argmin(np.linalg.norm(np.asarray(s["nodes"]) - np.asarray(point, float), axis=1)))
        value = _size(kind, share, s, fem, node)
        if name == "cantilever":
            Z, freqs = _cantilever_case(s, fem, kind, node, value)
        else:
            effect = {"kind": kind, "node": node, "value": value}
            K, M = st.matrices(fem, s["alpha"], effect, s)
            freqs = lines(st.modes_hz(fem, K, M, 4))
            Z = st.frf(fem, K, M, s["damping"], freqs)
        amp = np.abs(Z) * (1 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))
        file = f"{case.replace('%', 'pc')}.csv"
        label = f"node {node} r2" if kind == "patch" else f"node {node}"
        write_measured(OUT / file, MeasuredFRF(freqs, list(range(1, Z.shape[1] + 1)), amp, None,
                                               f"scikit-fem direct FRF of the {name} at alpha {s['alpha']} with "
                                               f"{kind} at {label} = {value:.6g}, {NOISE:.1%} noise, seed {seed}"))
        centre = (np.asarray(s["nodes"])[s["cells"][st.patch_cells(s["cells"], node)]].mean(axis=(0, 1))
                  if kind == "patch" else np.asarray(s["nodes"])[node])
        truth["cases"][case] = {"structure": name, "model": s["model"], "measured": f"data/cases/own_structures/{file}",
                                "effect": kind, "location": label, "node": node, "share": share,
                                "value": float(value), "xyz_m": [float(v) for v in centre], "seed": seed,
                                "frequencies_hz": [float(f) for f in freqs]}
        print(f"{case}: {kind} at {label} = {value:.5g}, lines {freqs.min():.1f}-{freqs.max():.1f} Hz", flush=True)
    for case, name, kind, size, seed, expected in CONTROL_CASES:
        s, fem = built[name]
        freqs, Z, entry = _control_case(s, fem, kind, size)
        amp = np.abs(Z) * (1 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))
        file = f"{case.replace('%', 'pc')}.csv"
        write_measured(OUT / file, MeasuredFRF(freqs, list(range(1, Z.shape[1] + 1)), amp, None,
                                               f"scikit-fem direct FRF of the {name} at alpha {s['alpha']}, "
                                               f"{entry['description']}, {NOISE:.1%} noise, seed {seed}"))
        truth["cases"][case] = {"structure": name, "model": s["model"], "measured": f"data/cases/own_structures/{file}",
                                "effect": kind, "expected": expected, **entry, "seed": seed,
                                "frequencies_hz": [float(f) for f in freqs]}
        print(f"{case}: {entry['description']}, lines {freqs.min():.1f}-{freqs.max():.1f} Hz", flush=True)
    (OUT / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.own_cases", __doc__)
    sys.exit(main())
