"""When should the MRGP loop hand over to the polish? FE runs to the noise floor by hand-over point.

    python -m benchmarks.handover                       # seeds 0-4, gradient and sao, benchmark + far-noisy
    python -m benchmarks.handover --seeds 0 1 --trainers gradient --datasets benchmark

For each data set, trainer and seed it runs the paper's loop alone (``flows.update
--no-polish``) for 3 iterations (60 FE runs), then, for k = 1, 2, 3, polishes
(``strategies.polish`` with the flow's settings: target 1e-4) from the best
sample after k iterations and counts the FE runs, loop and polish, until the
overall error first reaches the data set's noise floor (as in
``benchmarks.compare``). This is how the default ``polish_max_fe`` (the hand-over
point) was chosen. It also reports how far the hand-over sample is from the
true parameters: the loop's best-error samples lie in a long low-error valley,
not near the truth.

Writes ``docs/results/handover.md`` and prints it.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.compare import LOWER, REPO, UPPER, Oracle, datasets, first_reaching  # noqa: E402

Q = 20
POLISH_BUDGET = 400


def loop_runs(ds, trainer: str, seed: int, runs_dir: Path):
    """The paper's loop alone for 3 iterations; returns its run store."""
    from flows.config import UpdateConfig
    from flows.update import update_flow
    from tasks.runstore import RunStore

    run_id = f"{ds.name}-{trainer}-seed{seed}"
    config = UpdateConfig(run_id=run_id, runs_dir=str(runs_dir), measured=str(ds.path), trainer=trainer, seed=seed,
                          n_jobs=2, strategy="adaptive", polish=False, max_fe_evaluations=3 * Q, q=Q, true_parameters=ds.truth.tolist())
    update_flow(config)
    return RunStore(runs_dir / run_id)


def polish_from(ds, x0: np.ndarray, r0: np.ndarray) -> int | None:
    """FE runs of the polish from ``x0`` until the floor (None if not within the budget)."""
    from strategies.polish import polish

    oracle = Oracle(ds.path)
    polish(lambda pts: [oracle.residuals(p) for p in pts], x0, np.full(6, LOWER), np.full(6, UPPER),
           residuals0=r0, target=1e-4, max_evaluations=POLISH_BUDGET, stall_window=0)
    return first_reaching(np.array([e for _, e in oracle.history]), ds.floor)


def training_data(store, k: int):
    """(X (r, m), overall errors (r,)) of the successful FE runs of iterations 1..k (the run record)."""
    from tasks import record

    runs = record.fe_runs(store, k)
    ok = runs[runs["status"] == "ok"]
    return ok[record.parameter_columns(ok)].to_numpy(), ok["overall_error"].to_numpy()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.handover", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--trainers", nargs="+", default=["gradient", "sao"])
    p.add_argument("--datasets", nargs="+", default=["benchmark", "far-noisy"], choices=["benchmark", "far-noisy"])
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "handover.md"))
    args = p.parse_args(argv)
    runs_dir = REPO / "runs" / "handover"
    lines = ["| data set | trainer | seed | k | loop FE runs | best error at hand-over | its distance to the truth "
             "| polish FE runs to the floor | total |", "|" + "---|" * 9]
    totals: dict[tuple[str, int], list] = {}
    for ds in datasets(args.datasets):
        nominal = float(np.linalg.norm(ds.truth))
        print(f"{ds.name}: floor {ds.floor:.4%}; the nominal model is {nominal:.2f} from the truth", flush=True)
        for trainer in args.trainers:
            for seed in args.seeds:
                store = loop_runs(ds, trainer, seed, runs_dir)
                for k in (1, 2, 3):
                    X, E = training_data(store, k)
                    b = int(np.argmin(E))
                    n = polish_from(ds, X[b], Oracle(ds.path).residuals(X[b]))
                    total = None if n is None else len(E) + n
                    totals.setdefault((ds.name, k), []).append(total)
                    line = (f"| {ds.name} | {trainer} | {seed} | {k} | {len(E)} | {E[b]:.2%} | "
                            f"{np.linalg.norm(X[b] - ds.truth):.2f} | {n if n is not None else 'not reached'} | "
                            f"{total if total is not None else '-'} |")
                    lines.append(line)
                    print(line, flush=True)
    summary = ["| data set | k | reached the floor | total FE runs (median of those that did) | range |",
               "|---|---|---|---|---|"]
    for (name, k), t in totals.items():
        ok = [v for v in t if v is not None]
        summary.append(f"| {name} | {k} | {len(ok)} of {len(t)} | {int(np.median(ok)) if ok else '-'} | "
                       f"{f'{min(ok)}-{max(ok)}' if ok else '-'} |")
    cmd = "python -m benchmarks.handover" + (" " + " ".join(argv) if argv else "")
    text = (f"Command: `{cmd}` (seeds {', '.join(map(str, args.seeds))}; trainers {', '.join(args.trainers)}; "
            f"polish budget {POLISH_BUDGET}, target 1e-4, no stagnation stop)\n\n"
            + "\n".join(summary) + "\n\n" + "\n".join(lines) + "\n")
    Path(args.out).write_text(text)
    print("\n" + "\n".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
