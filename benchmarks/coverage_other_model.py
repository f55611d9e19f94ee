"""Coverage of the intervals on data from a model other than the fitted one, and the spread of a 20-set figure.

    nice -n 10 python -m benchmarks.coverage_other_model                 # 20 data sets from the finer mesh, ~3 min
    python -m benchmarks.coverage_other_model --data fine --n 20 --noise 0.01
    python -m benchmarks.coverage_other_model --spread-only              # only the 20-set spread (seconds)

Two questions of issue 30 (a hidden figure of 0.89 on 20 data sets from an independent model):

1. **Spread.** How far from 0.95 does the coverage of 20 data sets (120 intervals) fall by chance? From
   the project's own study (``docs/results/coverage-n500-runs.csv``: 500 data sets of the fitted model at 1 %
   noise, noise estimated), 20 of the data sets drawn without replacement, many times: the quantiles of
   the 20-set coverage and P(coverage <= 107/120). The six intervals of one data set share its noise
   draw and their errors are correlated, so 120 intervals are not 120 independent trials.
2. **Model error.** Data from another model: ``fine``, the benchmark's plates meshed twice as finely along
   x (``three_plate(refine=(2, 1, 1))``, a discretisation difference of ~4 % rms in the FRF, as between
   any FE model and a real structure), or ``mass``, the benchmark with segment 3's mass 10 % higher
   (``gamma``); truths uniform in [-TRUTH_RANGE, TRUTH_RANGE]^6, amplitudes ``|Z| (1 + sigma e)`` at the
   benchmark's 12 lines; the fitted coarse model's log-amplitude least squares from the truth +
   U(-0.05, 0.05); the Laplace intervals (noise estimated) and the residual check of the intervals stage
   (:func:`tasks.intervals.residual_check`). Printed: the coverage overall, and split by the check's
   verdict (noise: the intervals are reported as 95 %; structure: as conditional).
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
TRUTH_RANGE = 0.5
START_OFFSET = 0.05
RUNS_500 = REPO / "docs" / "results" / "coverage-n500-runs.csv"


def spread(size: int = 20, draws: int = 20000, seed: int = 0, path: Path = RUNS_500) -> dict:
    """Quantiles of the coverage of ``size`` data sets drawn from the 500-set study (1 % noise, estimated)."""
    runs = pd.read_csv(path)
    g = runs[(runs["noise"] == 0.01) & (runs["estimator"] == "estimated")]
    per_set = g.groupby("dataset")["covered"].sum().to_numpy()
    n_par = int(g.groupby("dataset")["covered"].size().iloc[0])
    rng = np.random.default_rng(seed)
    cov = np.array([per_set[rng.choice(per_set.size, size, replace=False)].sum() / (size * n_par)
                    for _ in range(draws)])
    from scipy import stats

    p = per_set.sum() / (per_set.size * n_par)
    threshold = round(0.89 * size * n_par)
    return {"sets": int(per_set.size), "coverage": float(p), "size": size,
            "q": {q: float(np.quantile(cov, q)) for q in (0.01, 0.025, 0.05, 0.5, 0.95, 0.975)},
            "threshold": f"{threshold}/{size * n_par}",
            "p_at_or_below": float((cov <= threshold / (size * n_par) + 1e-12).mean()),
            "p_binomial": float(stats.binom.cdf(threshold, size * n_par, p)),
            "in_target": float(((cov >= 0.92) & (cov <= 0.98)).mean())}


def data_model(which: str):
    from fe_core.benchmark import three_plate

    if which == "fine":
        return three_plate(refine=(2, 1, 1)), None
    if which == "mass":
        return three_plate(), np.array([0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
    raise ValueError(f"unknown data model {which!r}")


def one_dataset(k, sigma, seed, truth_model, gamma, fitted) -> dict:
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.inference.intervals import fit_log_amplitudes
    from fe_core.inference.laplace import laplace_intervals
    from tasks.intervals import residual_check

    rng = np.random.default_rng([seed, k])
    truth = rng.uniform(-TRUTH_RANGE, TRUTH_RANGE, fitted.n_segments)
    Z = truth_model.frf(truth, freqs, gamma=gamma)
    u = np.abs(Z) * (1.0 + sigma * rng.standard_normal(Z.shape))
    start = truth + rng.uniform(-START_OFFSET, START_OFFSET, truth.size)
    fit = fit_log_amplitudes(fitted, freqs, u, start, LOWER, UPPER, max_fe_runs=50)
    iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, lower=LOWER, upper=UPPER)
    check = residual_check(fit.residual, freqs, fitted.n_segments, None)
    return {"dataset": k, "covered": iv.contains(truth), "structured": bool(check and check["structured"]),
            "rms": check["rms"] if check else np.nan, "noise_sigma": iv.noise_sigma,
            "z": (fit.alpha - truth) / iv.std}


def other_model(which: str, n: int, sigma: float, seed: int) -> dict:
    from fe_core.benchmark import three_plate

    truth_model, gamma = data_model(which)
    fitted = three_plate()
    rows = [one_dataset(k, sigma, seed, truth_model, gamma, fitted) for k in range(n)]
    covered = np.array([r["covered"] for r in rows])
    structured = np.array([r["structured"] for r in rows])
    out = {"data": which, "n": n, "coverage": float(covered.mean()), "covered": int(covered.sum()),
           "of": int(covered.size), "structured_sets": int(structured.sum()),
           "median_rms": float(np.median([r["rms"] for r in rows])),
           "median_noise_estimate": float(np.median([r["noise_sigma"] for r in rows])),
           "sd_z": float(np.std(np.concatenate([r["z"] for r in rows])))}
    if (~structured).any():
        out["coverage_when_noise"] = float(covered[~structured].mean())
    if structured.any():
        out["coverage_when_structure"] = float(covered[structured].mean())
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.coverage_other_model", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", choices=("fine", "mass"), nargs="+", default=["fine", "mass"])
    p.add_argument("--n", type=int, default=20)
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--seed", type=int, default=30)
    p.add_argument("--spread-only", action="store_true")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    s = spread()
    print(f"spread: {s['size']} of the {s['sets']} data sets of docs/results/coverage-n500-runs.csv (1 % noise, coverage "
          f"{s['coverage']:.3f}): 20-set coverage quantiles " + ", ".join(f"{q:g}: {v:.3f}" for q, v in s["q"].items())
          + f"; P(<= {s['threshold']}) = {s['p_at_or_below']:.3f} (as 120 independent trials: "
          f"{s['p_binomial']:.4f}); P(in 0.92-0.98) = {s['in_target']:.3f}", flush=True)
    if not args.spread_only:
        for which in args.data:
            r = other_model(which, args.n, args.noise, args.seed)
            print(f"data from '{which}': {r['covered']} of {r['of']} covered ({r['coverage']:.3f}); residual check "
                  f"structure in {r['structured_sets']} of {r['n']} sets (median rms {r['median_rms']:.3%}, noise "
                  f"estimate {r['median_noise_estimate']:.3%}); coverage when the check says noise "
                  f"{r.get('coverage_when_noise', float('nan')):.3f}, when structure "
                  f"{r.get('coverage_when_structure', float('nan')):.3f}; sd of (estimate - truth)/std "
                  f"{r['sd_z']:.2f}", flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
