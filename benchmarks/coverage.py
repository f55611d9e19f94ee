"""Do the 95 % intervals hold? Their coverage over synthetic data sets (issue 19).

    nice -n 5 python -m benchmarks.coverage                    # 100 data sets per noise level, ~10 min on 2 cores
    python -m benchmarks.coverage --n 10 --noise 0.01 --out /tmp/cov   # a quick look

For each noise level (0.5 % and 1 % by default) and each data set k:

* a true alpha drawn uniformly from ``[-TRUTH_RANGE, TRUTH_RANGE]^6`` (seed
  ``seed + k``; at least 0.3 from the search box [-0.999, 1], where the
  linearisation is not in question: near a bound the flow flags the interval);
* a measurement ``u = |Z(alpha_true)| (1 + sigma e)``, ``e ~ N(0, 1)`` (the
  noise model of ``data/cases/three_plate_far_noisy/far_noisy.csv``), from the direct-solver FRF
  of the same FE model that is fitted: coverage asks whether the interval is
  right when the model is, so the data are not from another mesh here (model
  error is the closure's business, ``flows.diagnose``);
* the least-squares optimum of the log residual
  (:func:`fe_core.inference.intervals.fit_log_amplitudes`), started at the truth plus a
  uniform offset of +-``START_OFFSET`` per parameter (in the truth's basin: the
  question is the interval, not the search, which the update answers), with
  the exact Jacobian (Krylov, :mod:`fe_core.solvers.frf_derivatives`; scipy's trust region reflective); a fit whose
  cost is above the truth's is counted as a failed search and reported;
* the 95 % Laplace intervals (:func:`fe_core.inference.laplace.laplace_intervals`)
  with the noise estimated from the residual (Student t, ``N - m`` dof: what a
  run without ``--noise`` reports) and with the true noise given (normal).

Writes ``<out>.md`` (the table), ``<out>-runs.csv`` (one row per data set,
estimator and parameter) and prints the table.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOWER, UPPER = -0.999, 1.0
TRUTH_RANGE = 0.7
START_OFFSET = 0.05
LEVEL = 0.95

_MODEL = None


def _model():
    global _MODEL
    if _MODEL is None:
        from fe_core.benchmark import three_plate

        _MODEL = three_plate()
    return _MODEL


def one_dataset(k: int, sigma: float, seed: int) -> list[dict]:
    """Fit data set ``k`` at noise ``sigma``; one row per estimator and parameter."""
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.inference.intervals import fit_log_amplitudes
    from fe_core.inference.laplace import laplace_intervals

    from fe_core.solvers.sensitivity import log_amplitude_jacobian

    model = _model()
    rng = np.random.default_rng([seed, k, int(round(sigma * 1e6))])
    truth = rng.uniform(-TRUTH_RANGE, TRUTH_RANGE, model.n_segments)
    Z = model.frf(truth, freqs, method="direct")
    e = rng.standard_normal(Z.shape)
    u = np.abs(Z) * (1.0 + sigma * e)
    # The same noise draws through the model linearised at the truth (an exactly linear-Gaussian problem,
    # whose standardised errors are N(0, 1) by construction): the spread the draws themselves give.
    J_truth = log_amplitude_jacobian(model, truth, freqs)
    C_truth = np.linalg.inv(J_truth.T @ J_truth)
    z_linear = (C_truth @ J_truth.T @ (sigma * e.ravel())) / (sigma * np.sqrt(np.diag(C_truth)))
    start = truth + rng.uniform(-START_OFFSET, START_OFFSET, truth.size)
    t0 = time.perf_counter()
    fit = fit_log_amplitudes(model, freqs, u, start, LOWER, UPPER, max_fe_runs=50)
    seconds = time.perf_counter() - t0
    r_truth = np.log(np.abs(model.frf(truth, freqs))).ravel() - np.log(u).ravel()
    search_ok = bool(fit.residual @ fit.residual <= r_truth @ r_truth * (1 + 1e-9))
    rows = []
    for estimator, noise in (("estimated", None), ("given", sigma)):
        iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, noise=noise, level=LEVEL, lower=LOWER,
                               upper=UPPER)
        inside = iv.contains(truth)
        for i, name in enumerate(iv.names):
            rows.append({"noise": sigma, "dataset": k, "estimator": estimator, "parameter": name,
                         "truth": truth[i], "estimate": fit.alpha[i], "low": iv.low[i], "high": iv.high[i],
                         "width": iv.high[i] - iv.low[i], "covered": bool(inside[i]),
                         "z": (fit.alpha[i] - truth[i]) / iv.std[i], "z_linear": z_linear[i],
                         "noise_sigma": iv.noise_sigma,
                         "near_bound": bool(iv.near_bound[i]), "search_ok": search_ok, "fe_runs": fit.fe_runs,
                         "jacobians": fit.jacobians, "seconds": seconds})
    return rows


def table(runs: pd.DataFrame) -> pd.DataFrame:
    """Coverage per noise level and estimator: overall, per parameter, mean widths, failed searches."""
    out = []
    for (sigma, est), g in runs.groupby(["noise", "estimator"], sort=True):
        per = g.groupby("parameter")["covered"].mean()
        width = g.groupby("parameter")["width"].mean()
        n_sets = g["dataset"].nunique()
        row = {"noise": f"{sigma:.1%}", "sigma": est, "data sets": n_sets, "overall": g["covered"].mean(),
               "lowest parameter": f"{per.min():.3f} ({per.idxmin()})",
               "all 6 covered": g.groupby("dataset")["covered"].all().mean(),
               "sd of (estimate - truth) / std": g["z"].std(),
               "the same for the linearised model and the same draws": g["z_linear"].std()
               if "z_linear" in g else float("nan")}
        for name in per.index:
            row[f"{name} coverage / mean width"] = f"{per[name]:.2f} / {width[name]:.4f}"
        row["failed searches"] = int((~g.groupby("dataset")["search_ok"].first()).sum())
        out.append(row)
    return pd.DataFrame(out)


def fit_all(n: int, noise: list[float], seed: int, n_jobs: int, t0: float) -> pd.DataFrame:
    from joblib import Parallel, delayed

    jobs = [delayed(one_dataset)(k, s, seed) for s in noise for k in range(n)]
    rows = []
    for i, part in enumerate(Parallel(n_jobs=n_jobs, return_as="generator")(jobs), 1):
        rows.extend(part)
        if i % 20 == 0 or i == len(jobs):
            print(f"{i}/{len(jobs)} data sets fitted, {time.perf_counter() - t0:.0f} s", flush=True)
    return pd.DataFrame(rows)


def markdown(df: pd.DataFrame) -> str:
    def cell(v):
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=100, help="data sets per noise level (default 100)")
    p.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.01], help="relative amplitude noise levels")
    p.add_argument("--seed", type=int, default=19)
    p.add_argument("--n-jobs", type=int, default=2)
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "coverage"))
    p.add_argument("--from-runs", metavar="CSV", help="only rewrite the table from an earlier <out>-runs.csv")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    if args.from_runs:
        runs = pd.read_csv(args.from_runs)
        args.n, args.noise = runs["dataset"].nunique(), sorted(runs["noise"].unique().tolist())
    else:
        runs = fit_all(args.n, args.noise, args.seed, args.n_jobs, t0)
    tab = table(runs)
    per_set = runs.drop_duplicates(["noise", "dataset"])
    cost = (f"Per data set: the fit took a median of {per_set['fe_runs'].median():.0f} FE runs (Krylov FRFs) and "
            f"{per_set['jacobians'].median():.0f} exact Jacobians; the interval itself costs one exact Jacobian "
            f"(Krylov projection with the adjoint, about 2 FE runs of time) at the optimum. Median "
            f"{per_set['seconds'].median():.2f} s per fit (2 busy cores shared with other work).")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    runs.to_csv(out.with_name(out.name + "-runs.csv"), index=False)
    text = markdown(tab)
    setup = (f"Coverage of the 95 % Laplace intervals (fe_core.inference.intervals) on synthetic data sets: true alpha uniform "
             f"in [-{TRUTH_RANGE}, {TRUTH_RANGE}]^6, amplitudes |Z(alpha)| (1 + sigma e) from the direct-solver FRF "
             f"of the fitted FE model, least squares of the log amplitudes with the exact Jacobian started "
             f"at the truth + U(-{START_OFFSET}, {START_OFFSET}). Row 'estimated': sigma from the residual, "
             f"||r||^2 / (N - m), Student t with N - m = 66 dof (what a run without --noise reports); row 'given': "
             f"the true sigma, normal quantile. 'all 6 covered': data sets whose six intervals all contain the "
             f"truth. 'sd of (estimate - truth) / std': 1 when the standard deviations are right; beside it the same for the estimate of the model linearised at the truth with the very same noise draws, (J^T J)^-1 J^T sigma e (exactly N(0, 1) in distribution): how far the draws alone take the spread from 1 (the parameters are correlated, so 6 n values hold fewer independent ones). Binomial standard error of a coverage of 0.95 over n data sets: sqrt(0.95 * 0.05 / n) "
             f"(0.022 for n = 100 per parameter).")
    out.with_suffix(".md").write_text(
        f"Command: `python -m benchmarks.coverage --n {args.n} --noise {' '.join(map(str, args.noise))} "
        f"--seed {args.seed}`\n\n{setup}\n\n{text}\n\n{cost}\n")
    print(text)
    print(cost)
    print(f"wrote {out.with_suffix('.md')} and {out.name}-runs.csv ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
