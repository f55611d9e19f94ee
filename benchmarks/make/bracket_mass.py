"""Write the closure's speed case: the tet10 bracket (33,681 free DOFs) carrying a point mass it does not declare.

    python -m benchmarks.make.bracket_mass          # data/examples/bracket/measured_mass.csv, truth_mass.json

The data are the bracket model's own matrices (``model.toml``) at the example's true factors
(``truth.json``) plus a point mass of ``SHARE`` = 4 % of the bracket's mass at the node nearest
``POINT`` (the upper web, away from the sensors), 125 lines from 260 to 3400 Hz at the 6 sensors
(750 complex values), 1 % multiplicative Gaussian noise on the amplitude (seed ``SEED``). They are a
**speed case** (issue 28: 20-50k DOF tet10, ~750 lines), not a test of independence: the fitted model
and the data share the mesh. The FRF is the Krylov solver's (converged to 1e-10 relative; the direct
complex LU per line would take ~20 minutes at 125 lines); the largest difference to the direct solve
at ``--check`` lines (default 1, the first; each takes 15 s to minutes) is printed and written to the truth.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket"
SHARE = 0.04
POINT = (0.005, 0.06, 0.10)
FREQS_HZ = np.linspace(260.0, 3400.0, 125)
NOISE = 0.01
SEED = 28


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m benchmarks.make.bracket_mass", description=__doc__.split("\n\n")[0])
    p.add_argument("--check", type=int, default=1, help="lines checked against the direct solve")
    args = p.parse_args(argv)
    from fe_core.closure.effects import Applied, PointMass, extended_frf
    from flows.problem import load_model
    from tasks.io.measured import MeasuredFRF, write_measured

    model = load_model(str(HERE / "model.toml"))[0]
    alpha = np.asarray(json.loads((HERE / "truth.json").read_text())["alpha"], float)
    node = int(model.mesh.nearest_node(POINT, atol=None))
    mass = SHARE * float(model.total_mass())
    applied = [Applied(PointMass(model), f"node {node}", np.array([mass]))]
    t = time.perf_counter()
    Z = extended_frf(model, alpha, FREQS_HZ, applied)
    print(f"Krylov FRF at {FREQS_HZ.size} lines: {time.perf_counter() - t:.1f} s")
    idx = np.linspace(0, FREQS_HZ.size - 1, max(args.check, 1)).astype(int)[:args.check]
    check = FREQS_HZ[idx]
    Zd = extended_frf(model, alpha, check, applied, method="direct") if idx.size else None
    diff = float(np.max(np.abs(Z[idx] - Zd)) / np.max(np.abs(Zd))) if idx.size else float('nan')
    print(f"largest difference to the direct solve at {check.size} lines / largest response: {diff:.2e}")
    u = np.abs(Z) * (1.0 + NOISE * np.random.default_rng(SEED).standard_normal(Z.shape))
    out = HERE / "measured_mass.csv"
    write_measured(out, MeasuredFRF(frequencies_hz=FREQS_HZ, sensors=list(range(1, u.shape[1] + 1)), amplitude=u,
                                    source=f"bracket model.toml at truth.json's alpha + {mass:.4g} kg at node {node}, "
                                           f"Krylov FRF, {NOISE:.0%} noise, seed {SEED}"))
    truth = {"model": "model.toml", "alpha": alpha.tolist(), "effect": "point_mass", "node": node,
             "node_xyz_m": [float(c) for c in model.mesh.nodes[node]], "mass_kg": mass, "share_of_mass": SHARE,
             "total_mass_kg": float(model.total_mass()), "noise": NOISE, "seed": SEED,
             "frequencies_hz": [round(float(f), 4) for f in FREQS_HZ], "solver": "krylov",
             "krylov_vs_direct_max_relative": diff,
             "direct_checked_hz": [float(f) for f in check]}
    (HERE / "truth_mass.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {out} and {HERE / 'truth_mass.json'}: {mass:.4g} kg at node {node}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
