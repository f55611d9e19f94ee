"""Optimiser suite (issue 17): random true parameters, noise-free and 1 % noise, every FE run and round counted.

    nice -n 5 python -m benchmarks.suite                 # 24 truths x 2 noise levels x 5 methods, one process
    python -m benchmarks.suite --noise 0 --out a & python -m benchmarks.suite --noise 0.01 --out b   # both cores
    python -m benchmarks.suite --from-runs a-runs.csv b-runs.csv    # then one table (docs/results/suite.md) from both
    python -m benchmarks.suite --truths 3 --methods default dfo-ls-nominal --out /tmp/suite
    python -m benchmarks.suite --only 9 13 21 --noise 0 --methods default --out /tmp/hard   # some truths only

``--truths`` true parameter vectors uniform in [-0.9, 0.9]^6 (seed ``--seed``)
on the three-plate benchmark model. The "measured" amplitudes come from the
benchmark model's direct solver at the truth (the fits use the Krylov FRF;
noise-free, and with 1 % multiplicative Gaussian noise, seeded per truth):
this compares optimisers on the same model, it is not a model-error test.
Methods, all on the relative amplitude residuals of Eq. 5 in the box
[-0.999, 1]^6:

* ``default``: the product's default, ``flows.update`` with the hybrid
  strategy (run as the flow, in this process, ``n_jobs = 1``), budget
  ``--budget`` FE-run equivalents;
* ``paper``: the paper's loop, ``flows.update --strategy adaptive --no-polish``
  (Table 2: 20 uniform samples, 20 per iteration, 240 FE runs), trainer ``--trainer``;
* ``dfo-ls-nominal`` / ``dfo-ls-random``: DFO-LS 1.6 (library defaults) from
  alpha = 0 / from one uniform random start per truth (core-level calls);
* ``least-squares-nominal``: :func:`strategies.polish.polish` (trust-region
  least squares, forward-difference Jacobian in one batch) from alpha = 0.

Scoring: the floor is 1e-4 on noise-free data and the overall error at the
truth + 1e-4 with noise. "Rounds" are batches that must finish before the
next starts, with 20 workers (a batch of b runs is ceil(b / 20) rounds);
sequential DFO-LS has one round per FE run, the paper's loop one per
iteration. "FE-run equivalents" count an FE run with its exact Jacobian as
the CPU-time ratio of a Jacobian to an FE run measured at the start of this
run (printed and written to the table). Success: floor reached and, on
noise-free data, every parameter of the best point within 0.01 of the truth.
Writes ``<out>.md`` (the aggregated table) and ``<out>-runs.csv``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOWER, UPPER = -0.999, 1.0
WORKERS = 20
METHODS = ("default", "paper", "dfo-ls-nominal", "dfo-ls-random", "least-squares-nominal")


def jacobian_ratio(model, freqs, repeats: int = 20) -> float:
    """CPU time of an FE run with its exact Jacobian over that of an FE run (benchmark, one thread)."""
    from fe_core.solvers.sensitivity import frf_jacobian

    rng = np.random.default_rng(0)
    X = rng.uniform(-0.8, 0.8, (repeats, 6))
    for x in X[:3]:  # warm caches
        model.frf(x, freqs)
        frf_jacobian(model, x, freqs)
    t0 = time.process_time()
    for x in X:
        model.frf(x, freqs)
    fe = time.process_time() - t0
    t0 = time.process_time()
    for x in X:
        frf_jacobian(model, x, freqs)
    return (time.process_time() - t0) / fe


class Problem:
    """One truth and noise level; ``evaluate(points)`` is one round of FE runs, every one logged."""

    def __init__(self, model, freqs, truth, noise, seed):
        from fe_core.inference.residual import relative_residual

        self.model, self.freqs, self.truth, self.noise = model, freqs, truth, noise
        u = np.abs(model.frf(truth, freqs, method="direct"))
        if noise:
            u = u * (1.0 + noise * np.random.default_rng(seed).standard_normal(u.shape))
        self.u = u
        self._rel = relative_residual
        self.history: list[dict] = []  # round (at 20 workers), x, error, cost
        self.rounds = 0
        self.floor = (float(np.mean(np.abs(self.residuals(truth)))) if noise else 0.0) + 1e-4

    def residuals(self, x):
        return self._rel(np.abs(self.model.frf(np.asarray(x, float), self.freqs)), self.u).ravel()

    def evaluate(self, points):
        out = []
        for k, x in enumerate(points):
            r = self.residuals(x)
            self.history.append({"round": self.rounds + 1 + k // WORKERS, "x": np.asarray(x, float).copy(),
                                 "error": float(np.mean(np.abs(r))), "cost": 1.0})
            out.append(r)
        self.rounds += -(-len(points) // WORKERS)
        return out

    def write_measured(self, folder: Path) -> Path:
        from tasks.io.measured import MeasuredFRF, write_measured

        path = folder / "measured.csv"
        write_measured(path, MeasuredFRF(frequencies_hz=self.freqs, sensors=list(range(1, self.u.shape[1] + 1)),
                                         amplitude=self.u, source="benchmark model at a suite truth"))
        return path


def run_flow(prob: Problem, strategy: str, budget: int, seed: int, trainer: str, work: Path, ratio: float) -> dict:
    """The product through ``flows.update`` (in this process); fills ``prob.history``."""
    from flows.config import UpdateConfig
    from tasks.record import history as run_history
    from flows.update import update_flow
    from tasks.runstore import RunStore

    folder = Path(tempfile.mkdtemp(dir=work))
    measured = prob.write_measured(folder)
    settings = dict(run_id="run", runs_dir=str(folder / "runs"), measured=str(measured), seed=seed, trainer=trainer,
                    n_jobs=1, intervals=False, true_parameters=prob.truth.tolist(), strategy=strategy)
    if strategy == "hybrid":
        settings.update(max_fe_evaluations=budget)
    else:
        settings.update(polish=False)  # the paper's loop alone, Table 2 (240 FE runs)
    summary = update_flow(UpdateConfig(**settings))
    store = RunStore(folder / "runs" / "run")
    for h in run_history(store, summary["iterations"]):  # every FE run, failed ones included (error inf)
        if strategy == "hybrid":
            h["cost"] = ratio if h["jacobian"] else 1.0
        prob.history.append(h)
    return summary


def run_method(method: str, prob: Problem, budget: int, seed: int, trainer: str, work: Path, ratio: float) -> None:
    lower, upper = np.full(6, LOWER), np.full(6, UPPER)
    if method == "default":
        run_flow(prob, "hybrid", budget, seed, trainer, work, ratio)
    elif method == "paper":
        run_flow(prob, "adaptive", budget, seed, trainer, work, ratio)
    elif method.startswith("dfo-ls"):
        import dfols

        logging.getLogger("dfols").setLevel(logging.WARNING)
        x0 = np.zeros(6) if method.endswith("nominal") else np.random.default_rng(1000 + seed).uniform(LOWER, UPPER, 6)
        np.random.seed(0)
        dfols.solve(lambda x: prob.evaluate([x])[0], x0, bounds=(lower, upper), maxfun=budget, do_logging=False)
    elif method == "least-squares-nominal":
        from strategies.polish import polish

        polish(prob.evaluate, np.zeros(6), lower, upper, target=1e-4, max_evaluations=budget)
    else:
        raise ValueError(method)


def score(prob: Problem, noise: float) -> dict:
    rounds = np.array([h["round"] for h in prob.history])
    errors = np.array([h["error"] for h in prob.history])
    costs = np.cumsum([h["cost"] for h in prob.history])
    running = np.minimum.accumulate(np.where(np.isfinite(errors), errors, np.inf))
    hit = np.flatnonzero(running <= prob.floor)
    best = int(np.argmin(np.where(np.isfinite(errors), errors, np.inf)))
    perr = float(np.max(np.abs(prob.history[best]["x"] - prob.truth)))
    reached = bool(hit.size)
    return {"fe_runs": len(errors), "fe_equivalents": float(costs[-1]), "rounds": int(rounds.max()),
            "fe_to_floor": int(hit[0]) + 1 if reached else None,
            "fe_equivalents_to_floor": float(costs[hit[0]]) if reached else None,
            "rounds_to_floor": int(rounds[hit[0]]) if reached else None,
            "final_error": float(errors[best]), "largest_parameter_error": perr,
            "success": reached and (noise > 0 or perr <= 0.01)}


def _median(s: pd.Series, fmt="{:.0f}") -> str:
    s = s.dropna()
    return fmt.format(s.median()) if len(s) else "-"


def aggregate(runs: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (noise, method), g in runs.groupby(["noise", "method"], sort=False):
        rows.append({"noise": f"{noise:.0%}", "method": method, "truths": len(g),
                     "success": f"{int(g['success'].sum())}/{len(g)}",
                     "floor reached": f"{int(g['fe_to_floor'].notna().sum())}/{len(g)}",
                     "FE runs to floor (median)": _median(g["fe_to_floor"]),
                     "FE-run equivalents to floor (median)": _median(g["fe_equivalents_to_floor"], "{:.1f}"),
                     "rounds to floor at 20 workers (median)": _median(g["rounds_to_floor"]),
                     "largest parameter error (median)": f"{g['largest_parameter_error'].median():.4f}",
                     "largest parameter error (max)": f"{g['largest_parameter_error'].max():.4f}"})
    return pd.DataFrame(rows)


def paired(runs: pd.DataFrame) -> list[str]:
    """Default vs DFO-LS from nominal on the truths DFO-LS solves: medians of FE runs, equivalents and rounds."""
    lines = []
    for noise, g in runs.groupby("noise", sort=False):
        d = g[g.method == "dfo-ls-nominal"].set_index("truth")
        f = g[g.method == "default"].set_index("truth")
        if d.empty or f.empty:
            continue
        solved = list(d.index[d["success"]])
        if not solved:
            continue
        fd = f.loc[solved]
        lines.append(
            f"- {noise:.0%} noise, the {len(solved)} truths DFO-LS from nominal solves (default solves "
            f"{int(fd['success'].sum())} of them): median FE runs to the floor default "
            f"{_median(fd['fe_to_floor'])} (FE-run equivalents {_median(fd['fe_equivalents_to_floor'], '{:.1f}')}) "
            f"vs DFO-LS {_median(d.loc[solved, 'fe_to_floor'])}; median rounds default "
            f"{_median(fd['rounds_to_floor'])} vs DFO-LS {_median(d.loc[solved, 'rounds_to_floor'])} "
            f"(a third: {np.median(d.loc[solved, 'rounds_to_floor']) / 3:.1f})")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.suite", description=__doc__.split("\n\n")[0])
    p.add_argument("--truths", type=int, default=24)
    p.add_argument("--only", type=int, nargs="+", metavar="T",
                   help="run only these truths (indices 0 .. truths-1 of the vectors drawn), e.g. --only 9 13 21")
    p.add_argument("--seed", type=int, default=17)
    p.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.01])
    p.add_argument("--budget", type=int, default=400, help="FE runs (FE-run equivalents for the default) per "
                                                           "method and case; the paper's loop keeps Table 2's 240")
    p.add_argument("--trainer", default="gradient", help="MRGP trainer of the default's emulator and the paper's loop")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "suite"))
    p.add_argument("--from-runs", nargs="+", metavar="CSV",
                   help="no run: write the table from these <out>-runs.csv files (e.g. one per noise level)")
    args = p.parse_args(argv)
    if args.only and not all(0 <= t < args.truths for t in args.only):
        p.error(f"--only: truth indices must lie in 0 .. {args.truths - 1}")
    if args.from_runs:
        return write_tables(pd.concat([pd.read_csv(f) for f in args.from_runs], ignore_index=True), Path(args.out),
                            f"Tables from {', '.join(Path(f).name for f in args.from_runs)}.")
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate

    logging.getLogger("prefect").setLevel(logging.WARNING)
    model = three_plate()
    ratio = jacobian_ratio(model, MEASUREMENT_FREQUENCIES_HZ)
    print(f"an FE run with its Jacobian costs {ratio:.2f} FE runs (CPU time, this machine, now)", flush=True)
    truths = np.random.default_rng(args.seed).uniform(-0.9, 0.9, (args.truths, 6))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    records = []
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="suite-") as work:
        for noise in args.noise:
            for t, truth in enumerate(truths):
                if args.only and t not in args.only:
                    continue
                for method in args.methods:
                    prob = Problem(model, MEASUREMENT_FREQUENCIES_HZ, truth, noise, seed=args.seed * 1000 + t)
                    t0, c0 = time.perf_counter(), time.process_time()
                    run_method(method, prob, args.budget, t, args.trainer, Path(work), ratio)
                    rec = {"noise": noise, "truth": t, "method": method, **score(prob, noise),
                           "wall_seconds": round(time.perf_counter() - t0, 2),
                           "cpu_seconds": round(time.process_time() - c0, 2),
                           **{f"true_alpha_{i + 1}": float(v) for i, v in enumerate(truth)}}
                    records.append(rec)
                    print(f"noise {noise:.0%} truth {t:2d} {method:<22} FE {rec['fe_runs']:4d} to floor "
                          f"{rec['fe_to_floor']} ({rec['fe_equivalents_to_floor']} equiv.) rounds "
                          f"{rec['rounds_to_floor']} err {rec['final_error']:.2e} max|dalpha| "
                          f"{rec['largest_parameter_error']:.4f} {rec['wall_seconds']:.0f} s", flush=True)
                    pd.DataFrame(records).to_csv(out.with_name(out.name + "-runs.csv"), index=False)
    only = f" --only {' '.join(map(str, args.only))}" if args.only else ""
    head = (f"Command: `nice -n 5 python -m benchmarks.suite --truths {args.truths}{only} --seed {args.seed} --budget "
            f"{args.budget} --trainer {args.trainer} --noise {' '.join(map(str, args.noise))}` "
            f"({time.perf_counter() - t_start:.0f} s wall). An FE run with its exact Jacobian cost {ratio:.2f} FE runs "
            f"(CPU time ratio measured at the start of the run).")
    return write_tables(pd.DataFrame(records), out, head)


def write_tables(runs: pd.DataFrame, out: Path, head: str) -> int:
    """``<out>.md`` (``head``, the table, the paired comparison) from the per-run rows."""
    from benchmarks.compare import markdown_table

    out.parent.mkdir(parents=True, exist_ok=True)
    table = aggregate(runs)
    text = head + "\n\n" + "\n".join(markdown_table(table)) + "\n\n" + "\n".join(paired(runs)) + "\n"
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
