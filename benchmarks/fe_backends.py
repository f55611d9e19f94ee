"""Time of the FE stage for 200 FE runs: loky processes vs. a Dask LocalCluster.

::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.fe_backends

The stage is the run's own FE stage (:class:`tasks.fe_runs.FEStage`, as the driver runs every
strategy's batches: submit, write one Parquet file and one log line per result as it arrives, then
the stage's tables), on ``--runs`` uniform samples of the three-plate model (the paper loop's first
batch), in a fresh run folder each time. Cases:

- serial: ``n_jobs = 1`` (joblib runs in this process), the reference;
- loky, ``n_jobs = 2``: first call (spawns the workers, each builds the model)
  and later calls (workers and their cached model reused), median of ``--repeats``;
- Dask ``LocalCluster(n_workers=2, threads_per_worker=1, processes=True)``:
  cluster start, first stage, later stages (median), same samples.

Every case's results are checked to be identical to the serial ones.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from flows.config import UpdateConfig  # noqa: E402
from flows.problem import resolve  # noqa: E402
from strategies.paper import PaperOptions, first_samples  # noqa: E402
from tasks.fe_runs import FEStage  # noqa: E402
from tasks.runstore import RunStore  # noqa: E402


def stage_time(config: UpdateConfig) -> tuple[float, pd.DataFrame]:
    """Wall time of one FE stage (iteration 1) in a fresh run folder, and its responses table."""
    root = Path(config.runs_dir) / config.run_id
    problem = resolve(config)  # the model is read once per process (its file hashed once per call)
    X = first_samples(PaperOptions(q=config.q, seed=config.seed, emulate=config.emulate), problem.lower, problem.upper,
                      problem.nominal)
    t0 = time.perf_counter()
    stage = FEStage(RunStore(root), problem, config, 1, "fe", logging.getLogger("benchmarks.fe_backends"))
    stage.run(range(len(X)), X, [False] * len(X))
    stage.write({"n": len(X)})
    ran = stage.ran
    seconds = time.perf_counter() - t0
    assert ran == config.q, (ran, config.q)
    return seconds, RunStore(root).read_table(1, "fe", "responses")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=200, help="FE runs per stage (default 200)")
    parser.add_argument("--repeats", type=int, default=3, help="timed warm stages per backend (default 3)")
    parser.add_argument("--workers", type=int, default=2, help="loky n_jobs and Dask workers (default 2)")
    args = parser.parse_args(argv)

    from distributed import Client, LocalCluster

    counter = iter(range(10_000))
    results: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="fe-backends-") as tmp:
        def config(**kw) -> UpdateConfig:
            return UpdateConfig(runs_dir=tmp, run_id=f"run-{next(counter)}", q=args.runs, seed=0, polish=False,
                                max_fe_evaluations=args.runs, **kw)

        resolve(config())  # this process's model, built once, outside the timings
        serial_t, reference = stage_time(config(n_jobs=1))
        keep = ["sample_id", "frequency_hz", "sensor", "real", "imag"]

        def same(fe: pd.DataFrame) -> bool:
            return fe[keep].reset_index(drop=True).equals(reference[keep].reset_index(drop=True))

        identical = True
        t, fe = stage_time(config(n_jobs=args.workers))
        identical &= same(fe)
        results["loky first"] = [t]
        results["loky"] = []
        for _ in range(args.repeats):
            t, fe = stage_time(config(n_jobs=args.workers))
            identical &= same(fe)
            results["loky"].append(t)

        t0 = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.wait_for_workers(args.workers)
            cluster_start = time.perf_counter() - t0
            address = cluster.scheduler_address
            t, fe = stage_time(config(fe_backend="dask", dask_address=address))
            identical &= same(fe)
            results["dask first"] = [t]
            results["dask"] = []
            for _ in range(args.repeats):
                t, fe = stage_time(config(fe_backend="dask", dask_address=address))
                identical &= same(fe)
                results["dask"].append(t)

    loky, dask = float(np.median(results["loky"])), float(np.median(results["dask"]))
    print(f"FE stage, {args.runs} FE runs of the three-plate model (12 frequencies, 6 sensors), "
          f"{args.workers} workers; machine: {os.cpu_count()} cores, {platform.machine()}, "
          f"OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}")
    print()
    print(f"| {'case':<58} | {'time':>8} | {'per FE run':>10} |")
    print(f"|{'-' * 60}|{'-' * 10}|{'-' * 12}|")
    rows = [
        ("serial (n_jobs = 1, in this process)", serial_t),
        (f"loky, n_jobs = {args.workers}, first stage (spawns workers)", results["loky first"][0]),
        (f"loky, n_jobs = {args.workers}, later stages (median of {args.repeats})", loky),
        (f"Dask LocalCluster, {args.workers} workers: cluster start", cluster_start),
        (f"Dask LocalCluster, {args.workers} workers, first stage", results["dask first"][0]),
        (f"Dask LocalCluster, {args.workers} workers, later stages (median of {args.repeats})", dask),
    ]
    for name, t in rows:
        per = "" if "cluster start" in name else f"{t / args.runs * 1e3:.1f} ms"
        print(f"| {name:<58} | {t:>6.2f} s | {per:>10} |")
    print()
    print(f"Dask / loky (later stages): {dask / loky:.2f}; all FE tables identical to the serial one: {identical}")
    print("all timings:", {k: [round(x, 3) for x in v] for k, v in results.items()})
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
