"""Where the Laplace intervals' linearisation is poor: does the sampled posterior hold (issue 19)?

    nice -n 5 python -m benchmarks.posterior                       # 100 + 50 data sets, ~15 min on 2 idle cores
    python -m benchmarks.posterior --n 10 --truths far --out /tmp/post   # a quick look

For a fixed truth and many noise draws (``u = |Z_direct(truth)| (1 + sigma e)``, own seeds):
the least-squares optimum of the log residual (started at the truth + U(-0.05, 0.05), as
``benchmarks.coverage``), the Laplace intervals with the noise given, and what the intervals
stage does with them (:func:`tasks.intervals._check_and_sample` without the run folder): the
linearity check along the flagged parameters (an interval wider than 0.2 or crossing the box)
and, where it fails, the importance-sampled posterior on the FE model (``--budget`` FE runs).
Coverage of the truth and mean widths per parameter, for the Laplace intervals and for the
reported ones (sampled where the check failed).

Truths: ``far``, the truth of ``data/cases/three_plate_far_noisy/far_noisy.csv`` (alpha_4 = 0.8 near the upper
bound 1, alpha_3 and alpha_4 anti-correlated and wide: the check fails there), and
``actual``, the benchmark's truth (all inside, where the coverage study found the
linearisation right: how often the check fires for nothing). Writes ``docs/results/posterior.md``
and ``docs/results/posterior-runs.csv``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOWER, UPPER = -0.999, 1.0
START_OFFSET = 0.05


def _truth(name: str) -> np.ndarray:
    if name == "far":
        from benchmarks.compare import ALPHA_FAR

        return ALPHA_FAR
    from fe_core.benchmark import ALPHA_ACTUAL

    return ALPHA_ACTUAL


def one_dataset(name: str, k: int, sigma: float, seed: int, budget: int) -> list[dict]:
    from benchmarks.coverage import _model
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.inference.intervals import fit_log_amplitudes
    from fe_core.inference.laplace import laplace_intervals
    from tasks.intervals import _check_and_sample

    model = _model()
    truth = _truth(name)
    rng = np.random.default_rng([seed, k, int(round(sigma * 1e6)), 1 if name == "far" else 2])
    Z = model.frf(truth, freqs, method="direct")
    u = np.abs(Z) * (1.0 + sigma * rng.standard_normal(Z.shape))
    start = np.clip(truth + rng.uniform(-START_OFFSET, START_OFFSET, truth.size), LOWER, UPPER)
    t0 = time.process_time()
    fit = fit_log_amplitudes(model, freqs, u, start, LOWER, UPPER, max_fe_runs=50)
    iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, noise=sigma, lower=LOWER, upper=UPPER)
    refined = SimpleNamespace(intervals=iv, residual=fit.residual)
    fields, check, post = _check_and_sample(model, freqs, u, refined, LOWER, UPPER, budget, seed * 1000 + k)
    cpu = time.process_time() - t0
    rows = []
    for i, n in enumerate(iv.names):
        lo, hi = fields["intervals"][n]
        rows.append({"truth_name": name, "noise": sigma, "dataset": k, "parameter": n, "truth": truth[i],
                     "estimate": fit.alpha[i], "laplace_low": iv.low[i], "laplace_high": iv.high[i],
                     "laplace_covered": bool(iv.low[i] <= truth[i] <= iv.high[i]), "low": lo, "high": hi,
                     "covered": bool(lo <= truth[i] <= hi), "method": fields["interval_method"],
                     "checked": bool(check is not None and check.checked[i]),
                     "poor": bool(check is not None and check.poor[i]),
                     "ess": post.ess if post is not None else np.nan,
                     "fe_runs": (check.fe_runs if check is not None else 0) + (post.fe_runs if post else 0),
                     "cpu_seconds": cpu})
    return rows


def table(runs: pd.DataFrame) -> str:
    lines = ["| truth | data sets | sampled (check failed) | median ESS | intervals | overall coverage "
             "| per parameter: coverage / mean width |", "|---|---|---|---|---|---|---|"]
    for name, g in runs.groupby("truth_name", sort=False):
        sets = g.drop_duplicates("dataset")
        sampled = float(np.mean(sets["method"] != "laplace"))
        ess = sets["ess"].median()
        for label, cov, lo, hi in (("Laplace", "laplace_covered", "laplace_low", "laplace_high"),
                                   ("reported", "covered", "low", "high")):
            per = g.groupby("parameter", sort=False).apply(
                lambda p: f"{p[cov].mean():.2f} / {(p[hi] - p[lo]).mean():.3f}", include_groups=False)
            lines.append(f"| {name} | {len(sets)} | {sampled:.2f} | {'' if np.isnan(ess) else f'{ess:.0f}'} "
                         f"| {label} | {g[cov].mean():.3f} | " + ", ".join(f"{k} {v}" for k, v in per.items()) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.posterior", description=__doc__.splitlines()[0])
    p.add_argument("--truths", nargs="+", choices=("far", "actual"), default=["far", "actual"])
    p.add_argument("--n", type=int, nargs="+", default=[100, 50], help="data sets per truth (in that order)")
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--budget", type=int, default=400, help="FE runs of each sampled posterior")
    p.add_argument("--seed", type=int, default=19)
    p.add_argument("--n-jobs", type=int, default=2)
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "posterior"))
    args = p.parse_args(argv)
    from joblib import Parallel, delayed

    counts = dict(zip(args.truths, args.n + [args.n[-1]] * len(args.truths)))
    jobs = [delayed(one_dataset)(t, k, args.noise, args.seed, args.budget) for t in args.truths
            for k in range(counts[t])]
    rows, t0 = [], time.perf_counter()
    for i, part in enumerate(Parallel(n_jobs=args.n_jobs, return_as="generator")(jobs), 1):
        rows.extend(part)
        if i % 10 == 0 or i == len(jobs):
            print(f"{i}/{len(jobs)} data sets, {time.perf_counter() - t0:.0f} s", flush=True)
    runs = pd.DataFrame(rows)
    out = Path(args.out)
    runs.to_csv(out.with_name(out.name + "-runs.csv"), index=False)
    command = " ".join(["python -m benchmarks.posterior"] + (sys.argv[1:] if argv is None else list(argv)))
    sets = runs.drop_duplicates(["truth_name", "dataset"])
    sampled = sets[sets["method"] != "laplace"]
    cost = (f"CPU per data set (fit, check and sampling): median {sets['cpu_seconds'].median():.1f} s; a sampled "
            f"posterior took {sampled['fe_runs'].median():.0f} FE runs (median) "
            if len(sampled) else f"CPU per data set: median {sets['cpu_seconds'].median():.1f} s; nothing sampled")
    text = (f"Command: `{command}`\n\n{__doc__.split(chr(10) + chr(10), 2)[2].split('Writes')[0].strip()}\n\n"
            f"Noise {args.noise:.1%} (given), sampling budget {args.budget} FE runs.\n\n{table(runs)}\n\n{cost}.\n")
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
