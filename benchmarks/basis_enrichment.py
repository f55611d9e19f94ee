"""Does one point's basis serve Gauss-Newton's big steps? Derivative enrichment measured (issue 41).

    python -m benchmarks.make.large --dofs 40000 --out runs/large/40k
    python -m benchmarks.basis_enrichment --model runs/large/40k/model.toml --measured runs/large/40k/measured.csv

At the nominal point: one full-order FE run with its Jacobian (its Krylov space W), then two global bases as
``fe_core.solvers.reduced_basis`` builds them, the plain one (W) and the enriched one (W and its derivative
columns ``K0^-1 K_i W[:, :c]``, :func:`fe_core.solvers.reduced_basis.enrich_derivatives`). At points a step of 0.02
to 0.3 (max-norm) away along a fixed direction, each basis's reduced responses and Jacobian against a full-order
run there (the largest error per line relative to the line's largest response; the Jacobian's relative to each
direction's largest) and the check's estimate. Then Gauss-Newton (scipy's trust-region least squares on
``ln|Z|``) on the enriched reduced model alone from the nominal point, against truth.json, and a full-order run at
its end: how far its responses are from the reduced ones, and the full-order Gauss-Newton step from there.
Prints one JSON record per line.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--measured", type=Path, required=True)
    ap.add_argument("--steps", type=float, nargs="*", default=[0.02, 0.05, 0.1, 0.2, 0.3])
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)

    import pandas as pd
    from scipy.optimize import least_squares

    from benchmarks.reduced_rounds import _errors
    from fe_core.io import read_model
    from fe_core.solvers import pardiso, reduced_basis as rb
    from fe_core.solvers.frf import _shifted_solver, hz_to_rad
    from fe_core.solvers.sensitivity import frf_jacobian

    def emit(record):
        print(json.dumps(record), flush=True)

    emit({"model": str(args.model), "load_before": os.getloadavg()[0]})
    model = read_model(args.model)
    table = pd.read_csv(args.measured, comment="#")
    freqs = np.unique(table["frequency_hz"].to_numpy(float))
    m = model.n_parameters
    theta0, direction = np.zeros(m), np.where(np.arange(m) % 2 == 0, 1.0, -0.7)
    with pardiso.threads(args.threads):
        t = time.perf_counter()
        space: dict = {}
        frf_jacobian(model, theta0, freqs, space=space)
        W = space["basis"]
        emit({"dofs": int(model.n_dofs), "lines": int(freqs.size), "space": int(W.shape[1]),
              "full_run_s": round(time.perf_counter() - t, 1)})
        alpha, gamma = model.factors(theta0)
        solve, _ = _shifted_solver(model.stiffness(alpha), model.mass(gamma), None, 1.0)
        stiffness, mass = rb._parts(model)
        bases = {}
        for name in ("plain", "enriched"):
            t = time.perf_counter()
            basis = rb.ParametricBasis(stiffness, mass, model.combined_load(), model.outputs, solve, capacity=1000)
            basis.extend(W)
            if name == "enriched":
                rb.enrich_derivatives(basis, W, solve, stiffness[:model.n_segments])
            bases[name] = basis
            emit({"basis": name, "columns": basis.dim, "seconds": round(time.perf_counter() - t, 1)})

        def reduced(basis, theta):
            ws, wm = rb._weights(model, *model.factors(theta))
            Z, dZ, est = basis.evaluate(ws, wm, *model.damping, hz_to_rad(freqs), list(range(model.n_segments)), [])
            return Z[:, :, 0], dZ[:, :, 0, :], est

        for step in args.steps:
            theta = theta0 + step * direction
            Zf, dZf = frf_jacobian(model, theta, freqs)
            record = {"step": step}
            for name, basis in bases.items():
                Z, dZ, est = reduced(basis, theta)
                ez, edz = _errors(Z, dZ, Zf, dZf)
                record[name] = {"responses": float(f"{ez:.2e}"), "jacobian": float(f"{edz:.2e}"),
                                "estimate": float(f"{est.field_error.max():.2e}")}
            emit(record)

        order = list(dict.fromkeys(table["response"]))
        H = np.stack([table[table.response == r].sort_values("frequency_hz")[["real", "imag"]].to_numpy() @ [1, 1j]
                      for r in order], axis=1)
        truth_file = args.measured.parent / "truth.json"
        truth = np.array(list(json.loads(truth_file.read_text())["alpha"].values())) if truth_file.exists() else None
        enriched, memo = bases["enriched"], {}

        def at(x):
            key = tuple(x)
            if key not in memo:
                memo.clear()
                memo[key] = reduced(enriched, x)
            return memo[key]

        t = time.perf_counter()
        fit = least_squares(lambda x: (np.log(np.abs(at(x)[0] / H))).ravel(), theta0,
                            jac=lambda x: np.real(at(x)[1] / at(x)[0][:, :, None]).reshape(-1, m),
                            bounds=(-0.5, 0.5), method="trf")
        seconds = time.perf_counter() - t
        Zf, dZf = frf_jacobian(model, fit.x, freqs)
        r, J = np.log(np.abs(Zf / H)).ravel(), np.real(dZf / Zf[:, :, None]).reshape(-1, m)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        emit({"reduced_gauss_newton_s": round(seconds, 1), "evaluations": int(fit.nfev),
              "estimate_at_end": float(at(fit.x)[2].field_error.max()),
              "responses_rms_vs_full": float(np.sqrt(np.mean(np.abs(at(fit.x)[0] / Zf - 1) ** 2))),
              "full_order_step": float(np.max(np.abs(step))),
              "max_error_vs_truth": None if truth is None else float(np.max(np.abs(fit.x - truth))),
              "full_order_optimum_vs_truth": None if truth is None else float(np.max(np.abs(fit.x + step - truth))),
              "load_after": os.getloadavg()[0]})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
