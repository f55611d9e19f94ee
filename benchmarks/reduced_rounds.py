"""Where a large model's Gauss-Newton round goes, full order and through the global reduced basis (issue 41).

    python -m benchmarks.reduced_rounds --model runs/large/150k/model.toml --measured runs/large/150k/measured.csv

In one process, PARDISO on ``--threads`` threads (as the flow runs a large model's single FE run): the model
read; one factorisation of K at the start point; one full-order FE run with its exact Jacobian there (the
factor reused: Krylov solves, products with the segment matrices, the reduced evaluations of its convergence
test); the global basis built from its space (the check's k solves, every segment matrix projected); then, at
points a step of 1e-3, 1e-2 and 0.1 (max-norm) away along a fixed direction, the reduced evaluation with its
check against a full-order run there (its factor from conjugate gradients on the held one or refactored,
``fe_core.solvers.nearby``), their times, and the reduced model's errors against the full-order results. Prints
one JSON record and appends it to ``runs/scaling/results.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import time
from pathlib import Path

import numpy as np


def _errors(Z, dZ, Zf, dZf):
    p = Z.shape[0]
    size = np.abs(Zf).reshape(p, -1).max(axis=1)
    ez = float((np.abs(Z - Zf).reshape(p, -1).max(axis=1) / size).max())
    m = dZ.shape[-1]
    scaled = np.abs(dZ - dZf).reshape(p, -1, m).max(axis=1) / size[:, None]
    top = (np.abs(dZf).reshape(p, -1, m).max(axis=1) / size[:, None]).max(axis=0)
    return ez, float((scaled / top).max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--measured", type=Path, required=True)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=float, nargs="*", default=[1e-3, 1e-2, 0.1])
    args = ap.parse_args(argv)

    from fe_core.io import read_model
    from fe_core.solvers import pardiso, reduced_basis as rb
    from fe_core.solvers.frf import hz_to_rad, spd_solver
    from fe_core.solvers.sensitivity import frf_jacobian
    import pandas as pd

    out = {"kind": "reduced_rounds", "model": str(args.model), "threads": args.threads,
           "load_before": " ".join(f"{v:.2f}" for v in os.getloadavg())}
    try:
        out["commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                       check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        out["commit"] = None
    t = time.perf_counter()
    model = read_model(args.model)
    out["read_s"] = round(time.perf_counter() - t, 1)
    out["dofs"] = int(model.n_dofs)
    freqs = np.unique(pd.read_csv(args.measured, comment="#")["frequency_hz"].to_numpy(float))
    out["lines"] = int(freqs.size)
    m = model.n_parameters
    theta0 = np.zeros(m)
    direction = np.where(np.arange(m) % 2 == 0, 1.0, -0.7)
    with pardiso.threads(args.threads):
        t = time.perf_counter()
        solve = spd_solver(model.stiffness(model.factors(theta0)[0]))
        out["factorisation_s"] = round(time.perf_counter() - t, 1)
        t = time.perf_counter()
        space: dict = {}
        Z0, dZ0, info = frf_jacobian(model, theta0, freqs, return_info=True, space=space)
        out["full_run_on_held_factor_s"] = round(time.perf_counter() - t, 1)
        out["space_dimension"], out["krylov_solves"] = int(info.dimension), int(info.solves)
        t = time.perf_counter()
        x = solve(np.ones((model.n_dofs, 13)))
        out["one_block_of_13_solves_s"] = round(time.perf_counter() - t, 2)
        del x, solve
        # the basis as reduced_basis.frf_jacobian builds it after a full-order run
        alpha, gamma = model.factors(theta0)
        t = time.perf_counter()
        from fe_core.solvers.frf import _shifted_solver
        pre, _ = _shifted_solver(model.stiffness(alpha), model.mass(gamma), None, 1.0)
        stiffness, mass = rb._parts(model)
        basis = rb.ParametricBasis(stiffness, mass, model.combined_load(), model.outputs, pre)
        out["basis_sketch_s"] = round(time.perf_counter() - t, 1)
        t = time.perf_counter()
        basis.extend(space["basis"])
        out["basis_projection_s"] = round(time.perf_counter() - t, 1)
        basis.channels, basis.pick = None, (slice(None), 0)
        model.__dict__[rb._KEY] = basis
        del pre, space
        points = []
        for step in args.steps:
            theta = theta0 + step * direction
            ws, wm = rb._weights(model, *model.factors(theta))
            t = time.perf_counter()
            Z, dZ, est = basis.evaluate(ws, wm, *model.damping, hz_to_rad(freqs), list(range(model.n_segments)), [])
            reduced_s = time.perf_counter() - t
            t = time.perf_counter()
            Zf, dZf, infof = frf_jacobian(model, theta, freqs, return_info=True)
            full_s = time.perf_counter() - t
            ez, edz = _errors(Z[:, :, 0], dZ[:, :, 0, :], Zf, dZf)
            points.append({"step": step, "reduced_s": round(reduced_s, 2), "full_s": round(full_s, 1),
                           "estimate": float(est.field_error.max()), "served": est.ok,
                           "frf_error": ez, "jacobian_error": edz, "full_dimension": int(infof.dimension)})
            print(json.dumps(points[-1]), flush=True)
    out["points"] = points
    out["peak_rss_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2)
    out["load_after"] = " ".join(f"{v:.2f}" for v in os.getloadavg())
    text = json.dumps(out, indent=1)
    print(text)
    path = Path("runs/scaling/results.jsonl")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fh.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
