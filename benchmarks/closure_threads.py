"""The closure's main-process work on one core and on two: the exact search, its restarts and the screen.

    python -m benchmarks.closure_threads --run-id hb06 --runs-dir /path/to/runs      # a finished run
    python -m benchmarks.closure_threads --run-id hb06 --runs-dir ... --threads 1 2 --repeat 2

The closure's baseline, screen, exact search and decision run in the flow's main process while the FE workers wait
(:mod:`tasks.closure.steps`). Two levers put the second core to work there: :func:`fe_core.threads.thread_map`
(the exact search's joint fits, restarts and scans, the screen's blocks of diagonal derivatives, on threads) and
PARDISO's own threads (:func:`fe_core.solvers.pardiso.threads`, ``on_the_cores`` in the tasks). From the run's
model, data and parameters (its ``summary.json``), per thread count, wall and CPU seconds of:

- ``restarts``: :func:`fe_core.closure.far.search.alpha_restarts` (the baseline's 8 restarts on the reduced model);
- ``search``: :func:`fe_core.closure.far.search.exact_search` (the check step's search, 3 passes at most);
- ``response``: a :class:`~fe_core.closure.effects.extended.LinearisedResponse` (a factorisation of ``K`` and its
  Krylov space: PARDISO's threads);
- ``screen``: the point masses' derivatives at every node (``batch_derivatives``).

and whether the results are those of the first row (:func:`same`: the search's places in the same order, values
and sums of squares to 1e-6; the screen's derivatives to 1e-9 of the largest: PARDISO's threads sum in another
order, so the spaces differ in their last digits). Run it alone on the machine.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # as the flow runs (flows/environment.py)
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def _load(run_id: str, runs_dir: str):
    from flows.diagnose import closure_data, run_folder, run_problem

    _, summary, manifest = run_folder(run_id, runs_dir)
    problem = run_problem(manifest.get("config", {}))
    freqs, u = closure_data(problem.data, problem.model).complete()
    params = summary["parameters"]
    alpha = np.array([float(params[f"alpha_{i + 1}"]) for i in range(len(params))])
    return problem.model, freqs, u, alpha


def _timed(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t, time.process_time() - c


def measure(model, freqs, u, alpha, n: int) -> dict:
    """Every stage on ``n`` threads: {stage: (result, wall s, CPU s)}."""
    import fe_core.threads as threads
    from fe_core.closure.effects import build_library
    from fe_core.closure.effects.extended import LinearisedResponse
    from fe_core.closure.far.search import alpha_restarts, exact_search
    from fe_core.solvers import pardiso

    threads.THREADS = n
    library = build_library(model)
    mass = next(e for e in library if e.kind == "point_mass")
    out = {}
    with pardiso.threads(n):
        out["restarts"] = _timed(lambda: alpha_restarts(model, freqs, u, alpha, 8))
        out["search"] = _timed(lambda: exact_search(model, freqs, u, alpha, library)[0])
        lin, wall, cpu = _timed(lambda: LinearisedResponse(model, alpha, freqs))
        out["response"] = (None, wall, cpu)
        out["screen"] = _timed(lambda: lin.batch_derivatives(mass, mass.locations()))
    return out


def same(stage: str, a, b, rtol: float = 1e-6) -> bool:
    """The results of ``stage`` on two thread counts agree: the same places and kinds in the same order, values and
    sums of squares to ``rtol`` (PARDISO's threads change the spaces' last digits, and a fit's end with them; the
    thread pool alone changes nothing: ``tests/fe_core/test_threads.py`` holds that bit for bit)."""
    def close(x, y):
        return np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=rtol, atol=rtol)
    if stage == "restarts":
        return len(a) == len(b) and all(close(x, y) and close(r, s) for (x, r), (y, s) in zip(a, b))
    if stage == "search":
        return len(a) == len(b) and all((f.effect, f.location) == (g.effect, g.location) and close(f.values, g.values)
                                        and close(f.rss, g.rss) for f, g in zip(a, b))
    if stage == "screen":
        return bool(np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(a)))
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run-id", required=True)
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--repeat", type=int, default=1, help="measure each thread count this many times (alternating)")
    args = p.parse_args(argv)
    model, freqs, u, alpha = _load(args.run_id, args.runs_dir)
    print(f"{args.run_id}: {model.n_dofs} free DOFs, {freqs.size} lines x {u.shape[1]} channels, "
          f"{os.cpu_count()} cores")
    rows, first = [], None
    for _ in range(args.repeat):
        for n in args.threads:
            out = measure(model, freqs, u, alpha, n)
            first = first or out
            rows.append((n, out))
    print("| threads | " + " | ".join(f"{s} wall / CPU s" for s in first) + " | as the first row |")
    print("|---|" + "---|" * (len(first) + 1))
    for n, out in rows:
        differ = [s for s in first if not same(s, first[s][0], out[s][0])]
        print(f"| {n} | " + " | ".join(f"{out[s][1]:.1f} / {out[s][2]:.1f}" for s in first) + " | "
              + ("yes" if not differ else "no: " + ", ".join(differ)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
