"""How far an effect moves the natural frequencies, at a finished run's alpha-only fit: the figure the closure's size
rule reads (:mod:`fe_core.closure.far.plausible`), first order as the rule takes it and exactly on the reduced model.

    python -m benchmarks.heldout_shifts --run runs/heldout-heldout3/hc03 patch "node 1106 r2" -0.9617

For each mode in the band: the first-order relative shift ``d lambda / (2 lambda)`` on the reduced model's modes at
the closure's alpha-only start (``closure.json``'s ``parameters_before``), and the shift of the reduced model's own
eigenvalues with the effect added (a large softening is far from first order). A study, not a tuning.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def shifts(run: Path, kind: str, location: str, value: float) -> dict:
    """``{"first_order": [...], "reduced": [...]}``: relative shifts (fractions) of the modes in the band."""
    from benchmarks.heldout_crossband import stored
    from fe_core.closure.effects import Applied, build_library
    from fe_core.closure.far.plausible import frequency_shifts
    from fe_core.closure.far.reduced import ReducedModel

    model, freqs, _, _, alpha = stored(run)
    effect = {e.kind: e for e in build_library(model, [kind])}[kind]
    item = Applied(effect, location, np.array([value]))
    rm = ReducedModel(model, freqs, alpha, [])
    first = frequency_shifts(rm, alpha, item)
    mu0, _ = rm.modal(alpha)
    mu1, _ = ReducedModel(model, freqs, alpha, [item]).modal(alpha)
    keep = (mu0 > 0) & (mu0 <= (2 * np.pi * freqs.max()) ** 2)
    return {"first_order": first.tolist(), "reduced": (np.sqrt(mu1[:keep.sum()] / mu0[keep]) - 1.0).tolist()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_shifts", description=__doc__.split("\n")[0])
    p.add_argument("--run", type=Path, required=True, help="a finished run's folder with its closure")
    p.add_argument("kind", help="the effect's kind (patch, point_mass, grounded_spring, ...)")
    p.add_argument("location", help='its location as the closure names it ("node 1106 r2")')
    p.add_argument("value", type=float, help="its value (beta, kg, N/m)")
    args = p.parse_args(argv)
    out = shifts(args.run, args.kind, args.location, args.value)
    for name, s in out.items():
        print(f"{name} shifts, %: {np.round(100 * np.asarray(s), 3).tolist()} (largest {100 * np.max(np.abs(s)):.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
