"""Side by side: adaptive MRGP (+ polish) against the peers a user could run instead (issue 9).

    python -m benchmarks.compare                       # seeds 0 1 2, both data sets, 5-15 min on 2 cores
    python -m benchmarks.compare --seeds 0 --datasets benchmark --methods adaptive-gradient least-squares-nominal

Runs, in one process, on the same measured data and the same FE model:

* ``default``: the product's default, ``flows.update`` with no strategy flag
  (the hybrid strategy, issue 17), its FE runs with an exact Jacobian counted
  as the Jacobian/FE CPU-time ratio measured at the start of the run
  ("FE-run equivalents"), its rounds (batches at 20 workers) counted;
* ``paper-<trainer>``: the paper's loop alone (``--strategy adaptive
  --no-polish``, Table 2: 240 FE runs), trainers gradient, sao and pso;
* ``adaptive-<trainer>``: this project's flow (``flows.update``), trainers
  gradient, sao and pso, with the polish stage (default settings: 240 FE runs);
* ``conventional``: the paper's baseline, 300 uniform FE runs + one MRGP + the
  best of 10,000 predictions (Section 3.4);
* ``least-squares-nominal``, ``least-squares-random``: ``scipy.optimize.least_squares``
  (trust region reflective, forward-difference Jacobian) on the relative
  residuals of Eq. (5), from alpha = 0 and from uniform random starts;
* ``dfo-ls-nominal``, ``dfo-ls-random``: DFO-LS (Cartis, Fiala, Marteau and
  Roberts 2019), derivative-free Gauss-Newton on the same residuals: its
  Jacobian comes from a linear interpolation of the residual vectors at
  m + 1 points, updated with about one FE run per iteration, instead of
  m forward differences; library defaults (start radius 0.1, coordinate
  directions, so deterministic), same starts as least squares;
* ``bayes-opt``: Bayesian optimisation of the overall error (Eq. 6b) with the
  ``bayesian-optimization`` library (GP + acquisition), 240 FE runs;
* ``random-search``: 240 uniform FE runs.

Every FE run of every method is counted in evaluation order, so "FE runs to
reach 1 %" is read off each method's own history. Data sets: the benchmark
measurement (noise-free, SPEC's actual alpha) and ``data/cases/three_plate_far_noisy/far_noisy.csv``
(a true alpha far from the nominal model, 1 % multiplicative noise; written by
:func:`make_far_noisy` when missing). The noise floor of a data set is the
overall error at its true parameters (0 for noise-free data, where 1e-4 is
used); "floor" columns count a method as there when its error is within 1e-4
of it.

Writes ``<out>.md`` (the table) and ``<out>-runs.csv`` (one row per method, data set and seed) and prints
the table (the aggregated rows are the table; no second copy as CSV that no page shows).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
BUDGET = 240
LS_BUDGET = 1000
LOWER, UPPER = -0.999, 1.0
#: A true parameter vector far from the nominal model (alpha = 0).
ALPHA_FAR = np.array([0.7, -0.65, 0.5, 0.8, -0.55, 0.6])
FAR_NOISE = 0.01
FAR_SEED = 20261121
METHODS = ("default", "paper-gradient", "paper-sao", "paper-pso", "adaptive-gradient", "adaptive-sao",
           "adaptive-pso", "conventional", "least-squares-nominal", "least-squares-random", "dfo-ls-nominal",
           "dfo-ls-random", "bayes-opt", "random-search")
#: Methods whose FE runs go out one at a time (a round per FE run).
SEQUENTIAL = ("dfo-ls-nominal", "dfo-ls-random", "bayes-opt")
#: CPU time of an FE run with its exact Jacobian over an FE run's (set by main; benchmarks.suite.jacobian_ratio).
JACOBIAN_RATIO = {"value": 2.5}


@dataclass(frozen=True)
class Dataset:
    name: str
    path: Path
    truth: np.ndarray
    floor: float  # overall error at the truth (noise), 1e-4 for noise-free data


def make_far_noisy(path: Path) -> None:
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate
    from tasks.io.measured import MeasuredFRF, write_measured

    model = three_plate()
    Z = model.frf(ALPHA_FAR, MEASUREMENT_FREQUENCIES_HZ, method="direct")
    rng = np.random.default_rng(FAR_SEED)
    amplitude = np.abs(Z) * (1.0 + FAR_NOISE * rng.standard_normal(Z.shape))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_measured(path, MeasuredFRF(frequencies_hz=MEASUREMENT_FREQUENCIES_HZ,
                                     sensors=list(range(1, model.n_sensors + 1)), amplitude=amplitude,
                                     source=f"three_plate at {ALPHA_FAR.tolist()}, {FAR_NOISE:.0%} noise, "
                                            f"seed {FAR_SEED}"))


def datasets(names: list[str]) -> list[Dataset]:
    from fe_core.benchmark import ALPHA_ACTUAL

    out = []
    if "benchmark" in names:
        out.append(Dataset("benchmark", REPO / "data" / "benchmark" / "measured.csv", ALPHA_ACTUAL, 1e-4))
    if "far-noisy" in names:
        path = REPO / "data" / "cases" / "three_plate_far_noisy" / "far_noisy.csv"
        if not path.exists():
            make_far_noisy(path)
        oracle = Oracle(path)
        out.append(Dataset("far-noisy", path, ALPHA_FAR, oracle.error(ALPHA_FAR) + 1e-4))
    return out


class Oracle:
    """The FE model against one measurement, counting every evaluation in order."""

    def __init__(self, measured_path: Path):
        from fe_core.benchmark import three_plate
        from tasks.io.measured import read_measured

        self.model = three_plate()
        self.measured = read_measured(measured_path)
        self.history: list[tuple[np.ndarray, float]] = []

    def residuals(self, x) -> np.ndarray:
        from fe_core.inference.residual import relative_residual

        x = np.asarray(x, float)
        amp = np.abs(self.model.frf(x, self.measured.frequencies_hz))
        r = relative_residual(amp, self.measured.amplitude).ravel()
        self.history.append((x.copy(), float(np.mean(np.abs(r)))))
        return r

    def error(self, x) -> float:
        r = self.residuals(x)
        self.history.pop()
        return float(np.mean(np.abs(r)))


class _Budget(Exception):
    pass


# -- the methods: each returns the ordered history [(x, overall error), ...] ----------------------
def run_default(ds: Dataset, seed: int) -> list[tuple]:
    """The product's default (hybrid strategy): [(x, error, cost in FE-run equivalents, round), ...]."""
    from flows.config import UpdateConfig
    from tasks.record import history as run_history
    from flows.update import update_flow
    from tasks.runstore import RunStore

    run_id = f"{ds.name}-default-seed{seed}"
    runs_dir = REPO / "runs" / "compare"
    config = UpdateConfig(run_id=run_id, runs_dir=str(runs_dir), measured=str(ds.path), seed=seed, n_jobs=2,
                          true_parameters=ds.truth.tolist())
    assert config.strategy == "hybrid", config.strategy
    summary = update_flow(config)
    history = run_history(RunStore(runs_dir / run_id), summary["iterations"])
    return [(h["x"], h["error"], JACOBIAN_RATIO["value"] if h["jacobian"] else 1.0, h["round"]) for h in history]


def run_adaptive(ds: Dataset, seed: int, trainer: str, strategy: str = "adaptive",
                 polish: bool = True) -> list[tuple]:
    from flows.config import UpdateConfig
    from flows.update import update_flow
    from tasks.record import history as run_history
    from tasks.runstore import RunStore

    run_id = f"{ds.name}-{strategy}-{trainer}-seed{seed}" + ("" if polish else "-no-polish")
    runs_dir = REPO / "runs" / "compare"
    config = UpdateConfig(run_id=run_id, runs_dir=str(runs_dir), measured=str(ds.path), trainer=trainer,
                          strategy=strategy, seed=seed, n_jobs=2, true_parameters=ds.truth.tolist(),
                          polish=polish)
    summary = update_flow(config)
    # Every FE run in order, failed ones included (they cost an FE run): the loop's, then the polish's.
    history = [(h["x"], h["error"], 1.0, h["round"]) for h in run_history(RunStore(runs_dir / run_id),
                                                                          summary["iterations"])]
    return history


def run_least_squares(ds: Dataset, x0: np.ndarray) -> list[tuple[np.ndarray, float]]:
    from scipy.optimize import least_squares

    oracle = Oracle(ds.path)

    def fun(x):
        if len(oracle.history) >= LS_BUDGET:
            raise _Budget
        return oracle.residuals(x)

    try:
        least_squares(fun, x0, jac="2-point", bounds=(LOWER, UPPER), method="trf")
    except _Budget:
        pass
    return oracle.history


def run_dfols(ds: Dataset, x0: np.ndarray) -> list[tuple[np.ndarray, float]]:
    import logging

    import dfols

    logging.getLogger("dfols").setLevel(logging.WARNING)
    oracle = Oracle(ds.path)

    def fun(x):
        if len(oracle.history) >= LS_BUDGET:
            raise _Budget
        return oracle.residuals(x)

    np.random.seed(0)  # DFO-LS draws from numpy's global generator only on a restart
    try:
        dfols.solve(fun, x0, bounds=(np.full(6, LOWER), np.full(6, UPPER)), maxfun=LS_BUDGET, do_logging=False)
    except _Budget:
        pass
    return oracle.history


def run_bayes_opt(ds: Dataset, seed: int) -> list[tuple[np.ndarray, float]]:
    from bayes_opt import BayesianOptimization

    oracle = Oracle(ds.path)
    names = [f"a{i}" for i in range(6)]

    def target(**kw):
        return -oracle.residuals(np.array([kw[n] for n in names])).__abs__().mean()

    opt = BayesianOptimization(target, {n: (LOWER, UPPER) for n in names}, random_state=seed, verbose=0,
                               allow_duplicate_points=True)
    opt.maximize(init_points=20, n_iter=BUDGET - 20)
    return oracle.history


def run_random(ds: Dataset, seed: int) -> list[tuple[np.ndarray, float]]:
    oracle = Oracle(ds.path)
    rng = np.random.default_rng(seed)
    for x in rng.uniform(LOWER, UPPER, size=(BUDGET, 6)):
        oracle.residuals(x)
    return oracle.history


def run_method(method: str, ds: Dataset, seed: int):
    if method == "default":
        return run_default(ds, seed)
    if method.startswith("paper-"):
        return run_adaptive(ds, seed, method.split("-", 1)[1], polish=False)
    if method.startswith("adaptive-"):
        return run_adaptive(ds, seed, method.split("-", 1)[1])
    if method == "conventional":
        return run_adaptive(ds, seed, "gradient", strategy="conventional")
    if method == "least-squares-nominal":
        return run_least_squares(ds, np.zeros(6))
    if method == "least-squares-random":
        return run_least_squares(ds, np.random.default_rng(1000 + seed).uniform(LOWER, UPPER, 6))
    if method == "dfo-ls-nominal":
        return run_dfols(ds, np.zeros(6))
    if method == "dfo-ls-random":
        return run_dfols(ds, np.random.default_rng(1000 + seed).uniform(LOWER, UPPER, 6))
    if method == "bayes-opt":
        return run_bayes_opt(ds, seed)
    if method == "random-search":
        return run_random(ds, seed)
    raise ValueError(method)


# -- scoring ----------------------------------------------------------------------------------------
def first_reaching(errors: np.ndarray, level: float) -> int | None:
    hit = np.flatnonzero(np.minimum.accumulate(errors) <= level)
    return int(hit[0]) + 1 if hit.size else None


def score(history, ds: Dataset, sequential: bool = False) -> dict:
    """FE runs (and FE-run equivalents, rounds where the history has them) to 1 % and to the floor.

    ``history``: [(x, error)] or [(x, error, cost, round)]; a sequential method has a round per FE run.
    """
    errors = np.array([h[1] for h in history])
    costs = np.cumsum([h[2] if len(h) > 2 else 1.0 for h in history])
    rounds = (np.arange(1, len(history) + 1) if sequential
              else np.array([h[3] if len(h) > 3 else np.nan for h in history], float))
    best = int(np.nanargmin(errors))
    x = history[best][0]
    floor = first_reaching(errors, ds.floor)
    return {
        "fe_runs": len(history),
        "runs_to_1pct": first_reaching(errors, 0.01),
        "runs_to_floor": floor,
        "equivalents_to_floor": float(costs[floor - 1]) if floor else None,
        "rounds_to_floor": float(rounds[floor - 1]) if floor and np.isfinite(rounds[floor - 1]) else None,
        "final_error": float(errors[best]),
        "largest_parameter_error": float(np.max(np.abs(x - ds.truth))),
    }


def aggregate(runs: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (ds, method), g in runs.groupby(["dataset", "method"], sort=False):
        def med(col):
            v = g[col].dropna()
            if not len(v):  # rounds are not counted for every method
                return "-" if col != "runs_to_1pct" and g["runs_to_floor"].notna().any() else "not reached"
            return f"{int(np.median(v))}" + (f" ({len(v)}/{len(g)})" if len(v) < len(g) else "")
        rows.append({
            "dataset": ds, "method": method, "seeds": len(g),
            "FE runs to 1 % (median)": med("runs_to_1pct"),
            "FE runs to noise floor (median)": med("runs_to_floor"),
            "FE-run equivalents to floor (median)": med("equivalents_to_floor"),
            "rounds to floor at 20 workers (median)": med("rounds_to_floor"),
            "FE runs used (median)": int(g["fe_runs"].median()),
            "final overall error (median)": f"{g['final_error'].median():.3%}",
            "largest parameter error (median)": f"{g['largest_parameter_error'].median():.4f}",
            "wall time s (median)": f"{g['wall_seconds'].median():.1f}",
            "success 1 %": f"{g['runs_to_1pct'].notna().mean():.0%}",
            "success floor": f"{g['runs_to_floor'].notna().mean():.0%}",
        })
    return pd.DataFrame(rows)


def markdown_table(table: pd.DataFrame) -> list[str]:
    """Lines of a Markdown table of ``table`` (header, rule, one line per row)."""
    md = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    return md + ["| " + " | ".join(str(v) for v in row) + " |" for row in table.itertuples(index=False)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.compare", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--bo-seeds", type=int, nargs="+", default=[0],
                   help="seeds of the Bayesian-optimisation peer (about 5 min per run)")
    p.add_argument("--datasets", nargs="+", default=["benchmark", "far-noisy"], choices=["benchmark", "far-noisy"])
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "compare"), help="output path without suffix")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    records = []
    if "default" in args.methods:
        from benchmarks.suite import jacobian_ratio
        from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate

        JACOBIAN_RATIO["value"] = jacobian_ratio(three_plate(), MEASUREMENT_FREQUENCIES_HZ)
        print(f"an FE run with its Jacobian costs {JACOBIAN_RATIO['value']:.2f} FE runs (CPU time, now)", flush=True)
    for ds in datasets(args.datasets):
        print(f"data set {ds.name}: {ds.path.relative_to(REPO)}, noise floor {ds.floor:.4%}", flush=True)
        for method in args.methods:
            seeds = ([0] if method.endswith("-nominal")  # deterministic
                     else args.bo_seeds if method == "bayes-opt" else args.seeds)
            for seed in seeds:
                t0 = time.perf_counter()
                history = run_method(method, ds, seed)
                rec = {"dataset": ds.name, "method": method, "seed": seed,
                       **score(history, ds, sequential=method in SEQUENTIAL),
                       "wall_seconds": time.perf_counter() - t0}
                records.append(rec)
                print(f"  {method:<22} seed {seed}: {rec['fe_runs']:4d} FE runs, final {rec['final_error']:.4%}, "
                      f"to 1 %: {rec['runs_to_1pct']}, to floor: {rec['runs_to_floor']} "
                      f"({rec['equivalents_to_floor']} equiv., {rec['rounds_to_floor']} rounds), "
                      f"max |param err| {rec['largest_parameter_error']:.4f}, {rec['wall_seconds']:.0f} s", flush=True)
                pd.DataFrame(records).to_csv(out.with_name(out.name + "-runs.csv"), index=False)
    runs = pd.DataFrame(records)
    table = aggregate(runs)
    md = markdown_table(table)
    text = "\n".join(md) + "\n"
    out.with_suffix(".md").write_text(
        f"Command: `python -m benchmarks.compare --seeds {' '.join(map(str, args.seeds))} "
        f"--bo-seeds {' '.join(map(str, args.bo_seeds))} --datasets {' '.join(args.datasets)} "
        f"--methods {' '.join(args.methods)}`\n\n" + text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
