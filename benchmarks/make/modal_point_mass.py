"""Modal data with a point mass the model lacks: ``data/examples/modal/modes_point_mass.uff``.

The benchmark's 6 lowest modes at the 18 test nodes of the modal example, made by the SPEC's model
(:func:`fe_core.benchmark.three_plate`) at the actual alpha WITH a point mass of 0.15 kg (2.6 % of the
structure, on u_x, u_y, u_z of the top-surface node at x = 482.25 mm, y = 20 mm), 0.2 % frequency and 2 %
shape noise (seed 5). The model file ``model.toml`` has no such mass: the modal update's closure should name it
(docs/guide/modal-data.md).

    python -m benchmarks.make.modal_point_mass
"""

from __future__ import annotations

import numpy as np

from benchmarks.make import modal_example as example
from fe_core.benchmark import ALPHA_ACTUAL, three_plate
from fe_core.closure.effects import PointMass
from fe_core.solvers.modal import eigenmodes
from tasks.io.measured.modes import write_uff55

MASS_KG = 0.15
WHERE = (0.48225, 0.02, 0.01)  # m: on the top surface of segment 6, off the test points
SEED = 5


def modes_with_mass(mass_kg: float = MASS_KG, where=WHERE, seed: int = SEED, n_modes: int = example.N_MODES):
    """(node position (3,), measured modes) of the benchmark with the point mass, noisy."""
    spec = three_plate()
    node = spec.mesh.nearest_node(where, atol=None)
    alpha = np.asarray(ALPHA_ACTUAL, float)
    M = spec.mass() + PointMass(spec, nodes=[node]).terms(alpha, f"node {node}", np.array([mass_kg])).mass
    freqs, vecs = eigenmodes(spec.stiffness(alpha), M, n_modes)
    rows = spec.free_dofs.searchsorted([3 * spec.mesh.nearest_node(p) + 2 for p in example.test_points()])
    f, s = example.noisy(freqs, vecs[rows].T, seed=seed)
    return spec.mesh.nodes[node].copy(), example.as_modes(f, s)


def main() -> int:
    _, modes = modes_with_mass()
    path = write_uff55(example.OUT / "modes_point_mass.uff", modes)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.modal_point_mass", __doc__)
    raise SystemExit(main())
