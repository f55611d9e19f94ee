"""Which parameters to report on noisy data: the lowest Eq. (6b) error or the least-squares optimum (issue 19)?

    nice -n 5 python -m benchmarks.estimators                 # both parts, ~30 min on 2 busy cores
    python -m benchmarks.estimators --part synthetic --n 20   # a quick look

Two parts, both against the truth:

``synthetic``
    The data sets of ``benchmarks.coverage`` (same generator and seeds: true alpha
    uniform in [-0.7, 0.7]^6, ``u = |Z_direct(alpha)| (1 + sigma e)``). Two estimators
    from the same start (the truth + U(-0.05, 0.05)):

    * ``least squares``: the optimum of the noise-weighted log residual
      (:func:`fe_core.inference.intervals.fit_log_amplitudes`), the maximum likelihood estimate
      of the multiplicative Gaussian noise model;
    * ``lowest Eq. 6b``: the minimiser of the paper's overall error (mean absolute
      relative residual), found from the least-squares optimum by iteratively
      reweighted least squares with the exact Jacobian (weights ``1 / |e_i|``, steps
      accepted while the error falls); what a run's best sample approaches when the
      search is perfect.

``runs``
    Real updating runs (``python -m flows.update``, default settings, seeds 0 and 1) on
    ``data/cases/three_plate_far_noisy/far_noisy.csv`` (truth ``ALPHA_FAR``, 1 % noise) and
    ``data/cases/three_plate_effects/clean-seed{0..4}.csv`` (truth ``ALPHA_ACTUAL``, 0.5 % noise), with the
    polish and with ``--no-polish``: the reported ``parameters`` (the FE run with the
    lowest Eq. 6b error) against the least-squares optimum nearest them (a trust-region fit
    from them, :func:`fe_core.inference.intervals.fit_log_amplitudes`; after the polish it is where
    the intervals stage's Gauss-Newton steps end).

"Nearer the truth" is measured per data set in the metric of the Laplace covariance at
the least-squares optimum, ``d^2 = (x - truth)^T C^-1 (x - truth)`` (chi-square with 6
dof for a well-calibrated estimate), and plainly as the largest ``|x_i - truth_i|``.
Writes ``docs/results/estimators-synthetic.csv`` and ``docs/results/estimators-runs.csv`` (one per part: a
part run alone keeps the other's) and ``docs/results/estimators.md`` from both.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOWER, UPPER = -0.999, 1.0


def lowest_overall_error(model, freqs, u, start, std, max_iterations: int = 60):
    """Minimiser of Eq. 6b (mean |e|, ``e = |Z| / u - 1``) from ``start`` by reweighted least squares.

    Returns ``(alpha, error, jacobians)``.
    """
    from fe_core.solvers.sensitivity import log_amplitude_jacobian

    def at(a):
        J, Z = log_amplitude_jacobian(model, a, freqs, return_frf=True)
        e = (np.abs(Z) / u).ravel() - 1.0
        return e, (1.0 + e)[:, None] * J  # d e = (|Z| / u) d ln|Z|

    a = np.asarray(start, float)
    e, De = at(a)
    err = np.mean(np.abs(e))
    floor = 1e-6 * np.sqrt(np.mean(e**2))
    n = 1
    for _ in range(max_iterations):
        w = 1.0 / np.sqrt(np.maximum(np.abs(e), floor))
        step = np.linalg.lstsq(De * w[:, None], -e * w, rcond=None)[0]
        accepted = False
        for t in (1.0, 0.5, 0.25, 0.125):
            trial = np.clip(a + t * step, LOWER, UPPER)
            e_t, De_t = at(trial)
            n += 1
            if np.mean(np.abs(e_t)) < err:
                a, e, De, err, accepted = trial, e_t, De_t, np.mean(np.abs(e_t)), True
                break
        if not accepted or np.max(np.abs(t * step) / std) < 1e-3:
            break
    return a, float(err), n


def one_synthetic(k: int, sigma: float, seed: int) -> dict:
    from benchmarks.coverage import START_OFFSET, TRUTH_RANGE, _model
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.inference.intervals import fit_log_amplitudes
    from fe_core.inference.laplace import laplace_intervals

    model = _model()
    rng = np.random.default_rng([seed, k, int(round(sigma * 1e6))])  # as benchmarks.coverage
    truth = rng.uniform(-TRUTH_RANGE, TRUTH_RANGE, model.n_segments)
    Z = model.frf(truth, freqs, method="direct")
    u = np.abs(Z) * (1.0 + sigma * rng.standard_normal(Z.shape))
    start = truth + rng.uniform(-START_OFFSET, START_OFFSET, truth.size)
    fit = fit_log_amplitudes(model, freqs, u, start, LOWER, UPPER, max_fe_runs=50)
    iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, noise=sigma)
    l1, l1_err, n = lowest_overall_error(model, freqs, u, fit.alpha, iv.std)
    ls_err = float(np.mean(np.abs(np.abs(model.frf(fit.alpha, freqs)) / u - 1.0)))
    truth_err = float(np.mean(np.abs(np.abs(Z) / u - 1.0)))
    return {"noise": sigma, "dataset": k, **_distances("least squares", fit.alpha, truth, iv.covariance),
            **_distances("lowest Eq. 6b", l1, truth, iv.covariance), "error_ls": ls_err, "error_6b": l1_err,
            "error_truth": truth_err, "irls_jacobians": n}


def _distances(label: str, x, truth, cov) -> dict:
    d = np.asarray(x) - np.asarray(truth)
    return {f"{label}: d2": float(d @ np.linalg.solve(cov, d)), f"{label}: max_abs": float(np.max(np.abs(d)))}


def synthetic(n: int, noise: list[float], seed: int, n_jobs: int) -> pd.DataFrame:
    from joblib import Parallel, delayed

    jobs = [delayed(one_synthetic)(k, s, seed) for s in noise for k in range(n)]
    rows = []
    t0 = time.perf_counter()
    for i, row in enumerate(Parallel(n_jobs=n_jobs, return_as="generator")(jobs), 1):
        rows.append(row)
        if i % 20 == 0 or i == len(jobs):
            print(f"synthetic: {i}/{len(jobs)} data sets, {time.perf_counter() - t0:.0f} s", flush=True)
    return pd.DataFrame(rows)


def synthetic_table(df: pd.DataFrame) -> str:
    lines = ["| noise | data sets | estimator | mean d^2 (6 if calibrated) | median max abs error | LS nearer (d^2) "
             "| mean Eq. 6b error |", "|---|---|---|---|---|---|---|"]
    for sigma, g in df.groupby("noise"):
        nearer = float(np.mean(g["least squares: d2"] < g["lowest Eq. 6b: d2"]))
        for label, err in (("least squares", "error_ls"), ("lowest Eq. 6b", "error_6b")):
            lines.append(f"| {sigma:.1%} | {len(g)} | {label} | {g[f'{label}: d2'].mean():.2f} "
                         f"| {g[f'{label}: max_abs'].median():.4f} | "
                         f"{f'{nearer:.2f}' if label == 'least squares' else ''} | {100 * g[err].mean():.4f} % |")
        lines.append(f"| {sigma:.1%} | {len(g)} | (truth) | 0 | 0 | | {100 * g['error_truth'].mean():.4f} % |")
    return "\n".join(lines)


# -- real runs ---------------------------------------------------------------------------------------------
def _cases():
    from benchmarks.compare import ALPHA_FAR
    from fe_core.benchmark import ALPHA_ACTUAL

    cases = [("data/cases/three_plate_far_noisy/far_noisy.csv", ALPHA_FAR, 0.01)]
    cases += [(f"data/cases/three_plate_effects/clean-seed{k}.csv", ALPHA_ACTUAL, 0.005) for k in range(5)]
    return cases


def one_run(measured: str, truth, sigma: float, seed: int, polish: bool, runs_dir: Path) -> dict:
    from fe_core.benchmark import three_plate
    from fe_core.inference.intervals import fit_log_amplitudes
    from fe_core.inference.laplace import laplace_intervals
    from tasks.io.measured import read_measured

    run_id = f"{Path(measured).stem}-seed{seed}-{'polish' if polish else 'nopolish'}"
    cmd = [sys.executable, "-m", "flows.update", "--measured", measured, "--run-id", run_id, "--runs-dir",
           str(runs_dir), "--seed", str(seed), "--no-intervals"] + ([] if polish else ["--no-polish"])
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr[-2000:]}")
    summary = json.loads((runs_dir / run_id / "summary.json").read_text())
    reported = np.array(list(summary["parameters"].values()))
    m = read_measured(REPO / measured)
    model = three_plate()
    # The least-squares optimum nearest the reported point: a trust-region fit from it (after the polish it
    # is already there; after the MRGP loop alone plain Gauss-Newton steps can fail from that far).
    fit = fit_log_amplitudes(model, m.frequencies_hz, m.amplitude, reported, LOWER, UPPER, max_fe_runs=100)
    iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, noise=sigma)
    ls, cov = fit.alpha, iv.covariance
    return {"measured": measured, "seed": seed, "polish": polish, "fe_runs": summary["fe_evaluations"],
            "overall_error": summary["overall_error"], "seconds": time.perf_counter() - t0,
            "ls_fe_runs": fit.fe_runs, "ls_jacobians": fit.jacobians,
            **_distances("reported (lowest Eq. 6b)", reported, truth, cov),
            **_distances("least squares", ls, truth, cov),
            "step_in_std": float(np.max(np.abs(ls - reported) / iv.std))}


def runs(seeds: list[int], runs_dir: Path) -> pd.DataFrame:
    rows = []
    for measured, truth, sigma in _cases():
        for seed in seeds:
            for polish in (True, False):
                rows.append(one_run(measured, truth, sigma, seed, polish, runs_dir))
                r = rows[-1]
                print(f"runs: {measured} seed {seed} {'polish' if polish else 'no polish'}: reported d2 "
                      f"{r['reported (lowest Eq. 6b): d2']:.2f}, LS d2 {r['least squares: d2']:.2f}, "
                      f"{r['fe_runs']} FE runs, {r['seconds']:.0f} s", flush=True)
    return pd.DataFrame(rows)


def runs_table(df: pd.DataFrame) -> str:
    lines = ["| runs | n | reported (lowest Eq. 6b): mean d^2 | least squares: mean d^2 | LS nearer (d^2) "
             "| reported: median max abs error | LS: median max abs error | median distance between them (std) |",
             "|---|---|---|---|---|---|---|---|"]
    df = df.assign(noise=np.where(df["measured"].str.contains("far_noisy"), "far_noisy (1 %)", "clean-seed* (0.5 %)"))
    for (noise, polish), g in df.groupby(["noise", "polish"], sort=False):
        nearer = float(np.mean(g["least squares: d2"] < g["reported (lowest Eq. 6b): d2"]))
        lines.append(f"| {noise}, {'polish' if polish else '--no-polish'} | {len(g)} "
                     f"| {g['reported (lowest Eq. 6b): d2'].mean():.2f} | {g['least squares: d2'].mean():.2f} "
                     f"| {nearer:.2f} | {g['reported (lowest Eq. 6b): max_abs'].median():.4f} "
                     f"| {g['least squares: max_abs'].median():.4f} | {g['step_in_std'].median():.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.estimators", description=__doc__.splitlines()[0])
    p.add_argument("--part", choices=("synthetic", "runs", "both"), default="both")
    p.add_argument("--n", type=int, default=100, help="synthetic data sets per noise level")
    p.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.01])
    p.add_argument("--seed", type=int, default=19, help="of the synthetic data (benchmarks.coverage's default)")
    p.add_argument("--run-seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--n-jobs", type=int, default=2)
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "estimators"))
    args = p.parse_args(argv)
    command = " ".join(["python -m benchmarks.estimators"] + (sys.argv[1:] if argv is None else list(argv)))
    out = Path(args.out)
    syn_csv, runs_csv = out.with_name(out.name + "-synthetic.csv"), out.with_name(out.name + "-runs.csv")
    if args.part in ("synthetic", "both"):
        synthetic(args.n, args.noise, args.seed, args.n_jobs).to_csv(syn_csv, index=False)
    if args.part in ("runs", "both"):
        with tempfile.TemporaryDirectory(prefix="estimators-") as tmp:
            runs(args.run_seeds, Path(tmp)).to_csv(runs_csv, index=False)
    parts = [f"Last command: `{command}` (each part writes its CSV; this page is made from both)\n",
             __doc__.split("\n\n", 2)[2].split("Writes")[0].strip() + "\n"]
    if syn_csv.exists():
        parts += ["## Synthetic data sets\n", synthetic_table(pd.read_csv(syn_csv)) + "\n"]
    if runs_csv.exists():
        parts += ["## Updating runs\n", runs_table(pd.read_csv(runs_csv)) + "\n"]
    text = "\n".join(parts)
    out.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
