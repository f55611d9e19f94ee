"""Write measured data with an effect the benchmark model lacks, and clean noisy data.

    python -m benchmarks.make.effects            # data/cases/three_plate_effects/*.csv, truth.json

Each file is the FE model at the SPEC's actual alpha plus one effect (or none),
solved with the direct solver, with 0.5 % multiplicative noise on the
amplitude, ``u = |Z| (1 + 0.005 e)``, e standard normal from a fixed seed per
file (the complex values are scaled by the same factor). ``truth.json``
states each effect; it is for tests and reports only, never for the code
under test.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from fe_core.closure.effects import Applied, build_library, extended_frf
from tasks.io.measured import MeasuredFRF, write_measured

OUT = Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_effects"
NOISE = 0.005
CLEAN_SEEDS = (0, 1, 2, 3, 4)

#: name -> (effect kind, location: node coordinates in m or a label, value, seed of the noise)
EFFECTS = {
    "point_mass": ("point_mass", (0.158125, -0.040, 0.010), 0.12, 101),
    "grounded_spring": ("grounded_spring", (0.323375, 0.020, 0.010), 4.0e5, 102),
    "joint_band": ("joint_band", "joint x=230 mm", -0.75, 103),
    "segment_mass": ("segment_mass", "segment5", 0.30, 104),
    "damping": ("damping", "b", 3.0e-5, 105),
}


def noisy(Z: np.ndarray, seed: int) -> np.ndarray:
    """``Z (1 + NOISE e)``: multiplicative noise on the amplitude, phase kept."""
    return Z * (1.0 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))


def write(name: str, Z: np.ndarray, source: str) -> Path:
    model = three_plate()
    measured = MeasuredFRF(frequencies_hz=MEASUREMENT_FREQUENCIES_HZ, sensors=list(range(1, model.n_sensors + 1)),
                           amplitude=np.abs(Z), complex_frf=Z, source=source)
    path = OUT / f"{name}.csv"
    write_measured(path, measured)
    return path


def main() -> int:
    model = three_plate()
    library = {e.kind: e for e in build_library(model)}
    OUT.mkdir(parents=True, exist_ok=True)
    truth = {"noise": NOISE, "alpha": ALPHA_ACTUAL.tolist(), "model": "three_plate", "data": {}}
    for name, (kind, where, value, seed) in EFFECTS.items():
        effect = library[kind]
        if isinstance(where, tuple):
            node = model.mesh.nearest_node(where)
            location = f"node {node}"
            info = {"node": node, "coordinates_m": list(where)}
        else:
            location, info = where, {}
        Z = extended_frf(model, ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ,
                         [Applied(effect, location, np.array([value]))], method="direct")
        path = write(name, noisy(Z, seed), f"three_plate at ALPHA_ACTUAL + {kind} {value} at {location}, "
                                           f"{NOISE:.1%} noise, seed {seed}")
        truth["data"][path.name] = {"effect": kind, "location": location, **info, "parameter": effect.parameters[0],
                                    "value": value, "unit": _unit(effect, location), "seed": seed,
                                    **effect.describe(location)}
        print(f"wrote {path}")
    for seed in CLEAN_SEEDS:
        Z = extended_frf(model, ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, [], method="direct")
        path = write(f"clean-seed{seed}", noisy(Z, seed), f"three_plate at ALPHA_ACTUAL, {NOISE:.1%} noise, seed {seed}")
        truth["data"][path.name] = {"effect": None, "seed": seed}
        print(f"wrote {path}")
    (OUT / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {OUT / 'truth.json'}")
    return 0


def _unit(effect, location) -> str:
    if effect.kind == "damping":
        return "1/s" if location == "a" else "s"
    return effect.units[0]


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.effects", __doc__)
    sys.exit(main())
