"""Optimiser suite (issue 17): random true parameters, noise-free and 1 % noise, every FE run counted.

    nice -n 5 python -m benchmarks.suite                 # 24 truths x 2 noise levels, ~10-20 min on 1 core
    python -m benchmarks.suite --truths 3 --out /tmp/suite

``--truths`` true parameter vectors uniform in [-0.9, 0.9]^6 (seed ``--seed``)
on the three-plate benchmark model. The "measured" amplitudes come from the
benchmark model itself at the truth (noise-free, and with 1 % multiplicative
Gaussian noise, seeded per truth): this compares optimisers on the same
model, it is not a model-error test. Methods, all on the relative residuals of
Eq. 5 in the box [-0.999, 1]^6, with core-level calls (no Prefect) and one FE
run at a time:

* ``default``: :func:`mrgp_core.strategies.local_first` (DFO-LS from the
  nominal model, space-filling rounds of 20 and restarts when it stalls above
  the estimated noise);
* ``dfo-ls-nominal`` / ``dfo-ls-random``: DFO-LS 1.6 (library defaults) from
  alpha = 0 / from one uniform random start per truth;
* ``least-squares-nominal``: :func:`mrgp_core.polish.polish` (trust-region
  least squares, forward-difference Jacobian in one batch) from alpha = 0.

The paper's MRGP loop is not in this suite (240 FE runs and 12 GP trainings
per case); its figures are in docs/update-results.md and docs/compare.md.

Scoring: the floor is 1e-4 on noise-free data and the overall error at the
truth + 1e-4 with noise. "Rounds" are batches that must finish before the
next starts, with 20 workers (a batch of b runs is ceil(b / 20) rounds);
sequential DFO-LS has one round per FE run. Success: floor reached and, on
noise-free data, every parameter within 0.01 of the truth.
Writes ``<out>.md``, ``<out>.csv`` (aggregated) and ``<out>-runs.csv``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LOWER, UPPER = -0.999, 1.0
WORKERS = 20
METHODS = ("default", "dfo-ls-nominal", "dfo-ls-random", "least-squares-nominal")


class Problem:
    """One truth and noise level; ``evaluate(points)`` is one round, every FE run logged."""

    def __init__(self, model, freqs, truth, noise, seed):
        from mrgp_core import adaptive

        self.model, self.freqs, self.truth = model, freqs, truth
        u = np.abs(model.frf(truth, freqs))
        if noise:
            u = u * (1.0 + noise * np.random.default_rng(seed).standard_normal(u.shape))
        self.u = u
        self._rel = adaptive.relative_residuals
        self.history: list[tuple[int, np.ndarray, float]] = []  # (round at 20 workers, x, error)
        self.rounds = 0
        self.floor = (float(np.mean(np.abs(self.residuals(truth)))) if noise else 0.0) + 1e-4

    def residuals(self, x):
        return self._rel(np.abs(self.model.frf(np.asarray(x, float), self.freqs))[None], self.u)[0]

    def evaluate(self, points):
        out = []
        for k, x in enumerate(points):
            r = self.residuals(x)
            self.history.append((self.rounds + 1 + k // WORKERS, np.asarray(x, float).copy(),
                                 float(np.mean(np.abs(r)))))
            out.append(r)
        self.rounds += -(-len(points) // WORKERS)
        return out


def run_method(method: str, prob: Problem, budget: int, seed: int) -> None:
    lower, upper = np.full(6, LOWER), np.full(6, UPPER)
    if method == "default":
        from mrgp_core.strategies import local_first

        local_first(prob.evaluate, np.zeros(6), lower, upper, prob.freqs, max_evaluations=budget, batch=WORKERS,
                    seed=seed)
    elif method.startswith("dfo-ls"):
        import dfols

        logging.getLogger("dfols").setLevel(logging.WARNING)
        x0 = np.zeros(6) if method.endswith("nominal") else np.random.default_rng(1000 + seed).uniform(LOWER, UPPER, 6)
        np.random.seed(0)
        dfols.solve(lambda x: prob.evaluate([x])[0], x0, bounds=(lower, upper), maxfun=budget, do_logging=False)
    elif method == "least-squares-nominal":
        from mrgp_core.polish import polish

        polish(prob.evaluate, np.zeros(6), lower, upper, target=1e-4, max_evaluations=budget)
    else:
        raise ValueError(method)


def score(prob: Problem, noise: float) -> dict:
    rounds = np.array([h[0] for h in prob.history])
    errors = np.array([h[2] for h in prob.history])
    running = np.minimum.accumulate(np.where(np.isfinite(errors), errors, np.inf))
    hit = np.flatnonzero(running <= prob.floor)
    best = int(np.argmin(np.where(np.isfinite(errors), errors, np.inf)))
    perr = float(np.max(np.abs(prob.history[best][1] - prob.truth)))
    reached = bool(hit.size)
    return {"fe_runs": len(errors), "rounds": int(rounds.max()),
            "fe_to_floor": int(hit[0]) + 1 if reached else None,
            "rounds_to_floor": int(rounds[hit[0]]) if reached else None,
            "final_error": float(errors[best]), "largest_parameter_error": perr,
            "success": reached and (noise > 0 or perr <= 0.01)}


def aggregate(runs: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (noise, method), g in runs.groupby(["noise", "method"], sort=False):
        ok = g[g["fe_to_floor"].notna()]
        rows.append({"noise": f"{noise:.0%}", "method": method, "truths": len(g),
                     "success": f"{int(g['success'].sum())}/{len(g)}",
                     "floor reached": f"{len(ok)}/{len(g)}",
                     "FE runs to floor (median)": int(ok["fe_to_floor"].median()) if len(ok) else "-",
                     "rounds to floor at 20 workers (median)": int(ok["rounds_to_floor"].median()) if len(ok) else "-",
                     "largest parameter error (median)": f"{g['largest_parameter_error'].median():.4f}",
                     "largest parameter error (max)": f"{g['largest_parameter_error'].max():.4f}"})
    return pd.DataFrame(rows)


def paired(runs: pd.DataFrame) -> list[str]:
    """Default vs DFO-LS from nominal on the truths DFO-LS solves: median FE runs and rounds."""
    lines = []
    for noise, g in runs.groupby("noise", sort=False):
        d = g[g.method == "dfo-ls-nominal"].set_index("truth")
        f = g[g.method == "default"].set_index("truth")
        solved = d.index[d["fe_to_floor"].notna()]
        both = [t for t in solved if pd.notna(f.loc[t, "fe_to_floor"])]
        if both:
            lines.append(f"- {noise:.0%} noise, the {len(solved)} truths DFO-LS from nominal solves: median FE runs "
                         f"default {np.median(f.loc[both, 'fe_to_floor']):.0f} vs DFO-LS "
                         f"{np.median(d.loc[both, 'fe_to_floor']):.0f}; median rounds default "
                         f"{np.median(f.loc[both, 'rounds_to_floor']):.0f} vs DFO-LS "
                         f"{np.median(d.loc[both, 'rounds_to_floor']):.0f} (default reached the floor on "
                         f"{len(both)} of them)")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.suite", description=__doc__.split("\n\n")[0])
    p.add_argument("--truths", type=int, default=24)
    p.add_argument("--seed", type=int, default=17)
    p.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.01])
    p.add_argument("--budget", type=int, default=300, help="FE runs per method and case")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--out", default=str(REPO / "docs" / "suite"))
    args = p.parse_args(argv)
    from benchmarks.compare import markdown_table
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate

    model = three_plate()
    truths = np.random.default_rng(args.seed).uniform(-0.9, 0.9, (args.truths, 6))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    records = []
    for noise in args.noise:
        for t, truth in enumerate(truths):
            for method in args.methods:
                prob = Problem(model, MEASUREMENT_FREQUENCIES_HZ, truth, noise, seed=args.seed * 1000 + t)
                t0 = time.perf_counter()
                run_method(method, prob, args.budget, seed=t)
                rec = {"noise": noise, "truth": t, "method": method, **score(prob, noise),
                       "wall_seconds": round(time.perf_counter() - t0, 2),
                       **{f"true_alpha_{i + 1}": float(v) for i, v in enumerate(truth)}}
                records.append(rec)
                print(f"noise {noise:.0%} truth {t:2d} {method:<22} FE {rec['fe_runs']:4d} to floor "
                      f"{rec['fe_to_floor']} rounds {rec['rounds_to_floor']} err {rec['final_error']:.2e} "
                      f"max|dalpha| {rec['largest_parameter_error']:.4f}", flush=True)
                pd.DataFrame(records).to_csv(out.with_name(out.name + "-runs.csv"), index=False)
    runs = pd.DataFrame(records)
    table = aggregate(runs)
    table.to_csv(out.with_suffix(".csv"), index=False)
    md = markdown_table(table)
    text = (f"Command: `python -m benchmarks.suite --truths {args.truths} --seed {args.seed} --budget {args.budget}`"
            f"\n\n" + "\n".join(md) + "\n\n" + "\n".join(paired(runs)) + "\n")
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
