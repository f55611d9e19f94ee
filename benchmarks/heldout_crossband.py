"""Why the closure's half-band check drops an effect: each half's view of it, on a finished run.

    python -m benchmarks.heldout_crossband --run runs/heldout-heldout2/hb01 grounded_spring "node 6333" 70738
    python -m benchmarks.heldout_crossband --benchmark           # the three-plate case of tests/fe_core/test_crossband.py

The backward check (:func:`fe_core.closure.prune.prune`) drops an effect that does not carry over from one half of
the lines to the other (:func:`fe_core.closure.crossband.carries_over`: alpha and the effects refitted on one half
by one Gauss-Newton step, each prediction of the other half weighed by the noise). This prints, for one effect
refitted with alpha from the run's closure's alpha-only start (or the benchmark's fine-mesh case), the check's
verdict and per half:

- the effect's **signature** there: its noise-weighed Jacobian columns with alpha's (and the other effects')
  projected out, times its value: how far the effect moves that half's prediction in ways nothing else can;
- the weighed **residual** there, with the effect fitted; their ratio, the effect's view against what the model
  leaves in that half (its own error and the noise);
- the **value** one Gauss-Newton step fitted on that half alone gives the effect.

The ratio is the one the check's exception reads (:func:`fe_core.closure.crossband.excused`); its bar was set on
the held-out cases seen with this script (docs/results/held-out.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def halves(model, freqs, u, sigma, fit, j: int) -> list[dict]:
    """Per half of the lines (lower, upper): the effect ``j`` of ``fit``'s signature, the residual, their ratio and
    the value a one-step refit on that half alone gives it (the step as :func:`fe_core.closure.crossband` takes it)."""
    from fe_core.closure.crossband import columns, half_step, signatures, weighed

    Jw, r = weighed(model, freqs, u, fit.alpha, fit.applied, sigma)
    v = np.asarray(fit.applied[j].values, float)
    own = list(columns(fit.alpha, fit.applied, j))
    low = freqs <= np.median(freqs)
    seen = signatures(Jw, r, u.shape[1], own, v, (low, ~low))
    out = []
    for name, train, ratio in (("lower", low, seen[0]), ("upper", ~low, seen[1])):
        rows = np.repeat(train, u.shape[1])
        residual = float(np.linalg.norm(r[rows]))
        step, norms = half_step(Jw, r, rows)
        out.append({"half": name, "signature": ratio * residual, "residual": residual, "ratio": ratio,
                    "value_fitted_here": (v + (step / norms)[own]).tolist()})
    return out


def stored(run: Path):
    """``(model, freqs, u, sigma, alpha)``: a finished run's model, its complete lines and the noise they state, and
    the closure's alpha-only start (``closure.json``'s ``parameters_before``)."""
    from flows.diagnose import closure_data, run_problem

    cfg = json.loads((run / "manifest.json").read_text())["config"]
    closure = json.loads((run / "closure" / "closure.json").read_text())
    problem = run_problem(cfg)
    model = problem.model
    data = closure_data(problem.data, model)
    freqs, u = data.complete()
    sigma = np.broadcast_to(np.asarray(data.noise_spec(None).sigma, float), u.shape)
    return model, freqs, u, sigma, np.array(list(closure["parameters_before"].values()), float)


def from_run(run: Path, kind: str, location: str, value: float):
    """The run's model and complete lines, the noise they state, and the effect refitted with alpha from the
    closure's alpha-only start."""
    from fe_core.closure.effects import build_library
    from fe_core.closure.fits import fit_update

    model, freqs, u, sigma, alpha = stored(run)
    effect = {e.kind: e for e in build_library(model, [kind])}[kind]
    return model, freqs, u, sigma, [fit_update(model, freqs, u, alpha, effect, location, [value])]


def benchmark():
    """tests/fe_core/test_crossband.py's case: the three-plate model fitted to its 2 x 2 x 1 finer mesh with a 0.12 kg
    mass (0.5 % noise); the mass alone, then a spring to the ground and a segment mass factor beside it."""
    from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as F, three_plate
    from fe_core.closure.effects import Applied, GroundedSpring, PointMass, SegmentMass, extended_frf
    from fe_core.closure.fits import fit_update

    model, fine = three_plate(), three_plate(refine=(2, 2, 1))
    node = int(np.argmin(np.linalg.norm(fine.mesh.nodes - model.mesh.nodes[337], axis=1)))
    u = np.abs(extended_frf(fine, ALPHA_ACTUAL, F, [Applied(PointMass(fine), f"node {node}", np.array([0.12]))],
                            method="direct"))
    u = u * np.exp(0.005 * np.random.default_rng(5).standard_normal(u.shape))
    mass = fit_update(model, F, u, ALPHA_ACTUAL, PointMass(model), "node 337", [0.12])
    fits = [mass] + [fit_update(model, F, u, mass.alpha, e, where, start, prior=mass.applied)
                     for e, where, start in ((GroundedSpring(model), "node 615", [3.7e4]),
                                             (SegmentMass(model), "segment1", [-0.25]))]
    return model, np.asarray(F, float), u, np.full(u.shape, 0.005), fits


def main(argv=None) -> int:
    from fe_core.closure.crossband import carries_over

    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_crossband", description=__doc__.split("\n")[0])
    p.add_argument("--run", type=Path, help="a finished run's folder with its closure (closure/closure.json)")
    p.add_argument("effect", nargs="*", help="KIND LOCATION VALUE (with --run)")
    p.add_argument("--benchmark", action="store_true", help="the three-plate case instead of a run")
    args = p.parse_args(argv)
    if args.benchmark:
        model, freqs, u, sigma, fits = benchmark()
    elif args.run is not None and len(args.effect) == 3:
        model, freqs, u, sigma, fits = from_run(args.run, args.effect[0], args.effect[1], float(args.effect[2]))
    else:
        p.error("give --run RUN KIND LOCATION VALUE, or --benchmark")
    for fit in fits:
        j = len(fit.applied) - 1
        a = fit.applied[j]
        carries, note = carries_over(model, freqs, u, fit.alpha, fit.applied, j, sigma)
        print(f"{a.label()} = {np.round(a.values, 6).tolist()}: carries over {carries} ({note})")
        for h in halves(model, freqs, u, sigma, fit, j):
            print(f"  {h['half']}: signature {h['signature']:.4g}, residual {h['residual']:.4g}, ratio "
                  f"{h['ratio']:.3g}; fitted on this half alone: {np.round(h['value_fitted_here'], 6).tolist()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
