"""Harder closure data (issue 18): several effects, transducer masses, damage, sensor faults, far alpha.

    python -m benchmarks.make.closure_table           # data/cases/three_plate_closure_table/*.csv, truth.json

As :mod:`benchmarks.make.effects`: the benchmark FE model with effects, solved with the direct
solver (not the Krylov FRF the closure uses), 0.5 % multiplicative noise on the amplitude from a
fixed seed per file. ``truth.json`` is for tests and benchmarks only. The case ``outside_library``
has an effect no library kind represents: a spring *between* two nodes of different plates (a
bracket left on), not to ground.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.make.effects import NOISE, noisy
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from fe_core.closure.effects import DOFS_PER_NODE, Applied, Effect, Terms, _free_position, build_library, extended_frf
from tasks.io.measured import MeasuredFRF, write_measured

OUT = Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_closure_table"
#: Stiffness factors far from the nominal model (and from ALPHA_ACTUAL).
ALPHA_FAR = np.array([-0.45, 0.55, 0.4, -0.35, 0.5, -0.4])

#: name -> (alpha, [(kind, location: node coordinates in m, "patch" centre or a label, value)], seed)
CASES = {
    "two_effects": (ALPHA_ACTUAL, [("point_mass", (0.158125, -0.040, 0.010), 0.12),
                                   ("grounded_spring", (0.48225, 0.020, 0.010), 4.0e5)], 201),
    "transducer_mass": (ALPHA_ACTUAL, [("sensor_mass", "all sensors", 0.025)], 202),
    "damaged_patch": (ALPHA_ACTUAL, [("patch", (0.313, 0.0, 0.010), -0.6)], 203),
    "sensor_gain": (ALPHA_ACTUAL, [("sensor_gain", "sensor 3", 0.08)], 204),
    "far_point_mass": (ALPHA_FAR, [("point_mass", (0.08625, 0.030, 0.010), 0.15)], 205),
    "far_clean": (ALPHA_FAR, [], 206),
    "outside_library": (ALPHA_ACTUAL, [("node_tie", ((0.20125, 0.0, 0.010), (0.2715, 0.0, 0.010)), 3.0e6)], 207),
}


class NodeTie(Effect):
    """A spring between u_z of two nodes (not to ground): outside the closure's library."""

    kind = "node_tie"
    parameters = ("k",)
    units = ("N/m",)
    lower = (0.0,)
    upper = (np.inf,)
    scale = (1e5,)

    def __init__(self, model, a: int, b: int):
        super().__init__(model)
        self.pair = (a, b)

    def locations(self):
        return [f"nodes {self.pair[0]}-{self.pair[1]}"]

    def terms(self, alpha, location, values):
        import scipy.sparse as sp
        pos = _free_position(self.model)
        i, j = (pos[DOFS_PER_NODE * n + 2] for n in self.pair)
        k = float(values[0])
        K = sp.csr_matrix(([k, -k, -k, k], ([i, i, j, j], [i, j, i, j])), shape=(self.model.n_dofs,) * 2)
        return Terms(stiffness=K)


def place(model, library, kind, where):
    """(effect, location, facts) of one truth entry."""
    if kind == "node_tie":
        a, b = (model.mesh.nearest_node(p) for p in where)
        effect = NodeTie(model, a, b)
        return effect, effect.locations()[0], {"nodes": [a, b]}
    effect = library[kind]
    if kind == "patch":
        centres = {int(loc.split()[1]) for loc in effect.locations()}
        xyz = model.mesh.nodes[sorted(centres)]
        node = sorted(centres)[int(np.argmin(np.linalg.norm(xyz - np.asarray(where), axis=1)))]
        return effect, f"node {node} r2", {"node": node, "cells": int(effect.bands[f"node {node} r2"].size)}
    if isinstance(where, tuple):
        node = model.mesh.nearest_node(where)
        return effect, f"node {node}", {"node": node}
    return effect, where, {}


def main() -> int:
    model = three_plate()
    library = {e.kind: e for e in build_library(model)}
    OUT.mkdir(parents=True, exist_ok=True)
    truth = {"noise": NOISE, "model": "three_plate", "data": {}}
    for name, (alpha, effects, seed) in CASES.items():
        applied, entries = [], []
        for kind, where, value in effects:
            effect, location, facts = place(model, library, kind, where)
            applied.append(Applied(effect, location, np.array([value])))
            entries.append({"effect": kind, "location": location, "value": value, "unit": effect.units[0], **facts})
        Z = noisy(extended_frf(model, alpha, MEASUREMENT_FREQUENCIES_HZ, applied, method="direct"), seed)
        measured = MeasuredFRF(frequencies_hz=MEASUREMENT_FREQUENCIES_HZ, sensors=list(range(1, model.n_sensors + 1)),
                               amplitude=np.abs(Z), complex_frf=Z,
                               source=f"three_plate + {', '.join(a.label() for a in applied) or 'nothing'}, "
                                      f"{NOISE:.1%} noise, seed {seed}")
        path = OUT / f"{name}.csv"
        write_measured(path, measured)
        truth["data"][path.name] = {"alpha": list(map(float, alpha)), "effects": entries, "seed": seed,
                                    "in_library": all(e["effect"] in library for e in entries)}
        print(f"wrote {path}")
    (OUT / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {OUT / 'truth.json'}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.closure_table", __doc__)
    sys.exit(main())
