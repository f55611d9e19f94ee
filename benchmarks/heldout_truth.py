"""How far the model is from a held-out case's data at the case's truth, against the closure's fit.

    python -m benchmarks.heldout_truth --run runs/heldout-heldout9/hi07 --case data/cases/held_out/heldout9/hi07

A closure that places an effect beside its true place, or sizes it off, either stopped in a wrong basin or fitted
the model's own error (the data come from another assembly: another mesh, element or geometry). One FE evaluation
each tells which: the sum of squares of ``ln(|Z_model| / u)`` over the closure's complete lines

- at the truth: the case's factors (``truth.json``) and its effect at its node and size;
- at the closure's fit: its factors and effects (``closure.json``'s ``parameters_after``);
- at the fit's factors with the true effect, and with the found effect at the true node and at the found size.

A truth far above the fit means the model's own error moved the optimum: no search finds the truth there. Nodal
effects of the library (point masses, springs to the ground) only; the noise alone would give about
``n * sigma**2`` (printed).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

NODAL = ("point_mass", "grounded_spring", "grounded_spring_x", "grounded_spring_y", "grounded_spring_z")


def rss(model, freqs, u, alpha, applied) -> float:
    from fe_core.closure.effects.extended import extended_frf

    return float(np.sum(np.log(np.abs(extended_frf(model, alpha, freqs, applied)) / u) ** 2))


def rows(run: Path, case: Path) -> list[tuple[str, float]]:
    from benchmarks.heldout_crossband import stored
    from fe_core.closure.effects import Applied, build_library

    truth = json.loads((case / "truth.json").read_text())
    kind = truth["effect"].get("library_kind") or truth["effect"]["kind"]
    if kind not in NODAL:
        raise SystemExit(f"error: {case / 'truth.json'}: effect {kind!r} is not a nodal effect of the library "
                         f"({', '.join(NODAL)})")
    closure = json.loads((run / "closure" / "closure.json").read_text())
    model, freqs, u, sigma, _ = stored(run)
    after = closure["parameters_after"]
    alpha_fit = np.array([v for k, v in after.items() if k.startswith("alpha_")], float)
    found = [(k.split(".")[0].split("@"), v) for k, v in after.items() if not k.startswith("alpha_")]
    library = {e.kind: e for e in build_library(model, sorted({kind} | {f[0][0] for f in found}))}
    true = Applied(library[kind], f"node {truth['effect']['node']}", np.array([truth["effect"]["value"]]))
    fitted = [Applied(library[k], loc, np.array([v])) for (k, loc), v in found]
    out = [("noise alone (n sigma^2)", float(np.sum(np.asarray(sigma, float) ** 2))),
           ("the truth: its factors and effect", rss(model, freqs, u, np.array(truth["factors"], float), [true])),
           ("the closure's fit", rss(model, freqs, u, alpha_fit, fitted)),
           ("the fit's factors, the true effect", rss(model, freqs, u, alpha_fit, [true]))]
    same = [a for a in fitted if a.effect.kind == kind]
    if same:
        moved = Applied(library[kind], true.location, same[0].values)
        out.append((f"the fit's factors, the found size {same[0].values[0]:.4g} at the true node",
                    rss(model, freqs, u, alpha_fit, [moved])))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_truth", description=__doc__.split("\n")[0])
    p.add_argument("--run", type=Path, required=True, help="the case's run folder, with its closure")
    p.add_argument("--case", type=Path, required=True, help="the case's folder (truth.json)")
    args = p.parse_args(argv)
    for label, value in rows(args.run, args.case):
        print(f"{label:55s} sum of squares {value:10.4g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
