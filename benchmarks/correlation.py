"""Speed of the correlation analysis (Section 3.5): N FE samples on n processes, then Eq. 16 and the SVD.

::

    python -m benchmarks.correlation --samples 10000 --n-jobs 2

Runs the same plain functions as ``python -m flows.correlation`` (without
Prefect) in a temporary folder and reports the wall time of each part, the
CPU time the FE workers used, and the machine's load average before and
after: on a shared machine the wall time depends on what else runs, while
``CPU seconds / n_jobs`` is what the FE stage needs with the cores to itself.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402

from joblib import Parallel, delayed  # noqa: E402

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ  # noqa: E402
from tasks import correlation as corr  # noqa: E402

TARGET_SECONDS = 600.0  # issue 6: N = 10,000 in under 10 minutes on 2 cores


def _timed_chunk(folder: str, chunk: int, meta: dict) -> tuple[int, float]:
    t0 = time.process_time()
    corr.evaluate_chunk(folder, chunk, meta)
    return chunk, time.process_time() - t0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    meta = {"model": "three_plate", "frequencies_hz": MEASUREMENT_FREQUENCIES_HZ.tolist(), "seed": args.seed,
            "chunk_size": 50, "n_parameters": 6, "lower": -1.0, "upper": 1.0}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-correlation-") as tmp:
        folder = Path(tmp)
        corr.prepare_folder(folder, meta)
        chunks = corr.chunks_needed(args.samples, meta["chunk_size"])
        t0 = time.perf_counter()
        cpu = 0.0
        parallel = Parallel(n_jobs=args.n_jobs, backend="loky", return_as="generator_unordered")
        for _, seconds in parallel(delayed(_timed_chunk)(str(folder), c, meta) for c in chunks):
            cpu += seconds
        fe_wall = time.perf_counter() - t0
        t1 = time.perf_counter()
        X, A, columns, failed = corr.load_amplitudes(folder, args.samples, meta)
        corr.correlation_table(X, A, columns)
        pearson_wall = time.perf_counter() - t1
        t2 = time.perf_counter()
        corr.sensitivity_tables("three_plate", {"alpha = 0": [0.0] * 6, "actual": ALPHA_ACTUAL},
                                MEASUREMENT_FREQUENCIES_HZ, 0.01, 0.05)
        sens_wall = time.perf_counter() - t2
    load_after = os.getloadavg()
    n = len(chunks) * meta["chunk_size"]
    total = fe_wall + pearson_wall + sens_wall
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"load average before {load_before[0]:.1f}, after {load_after[0]:.1f} (1 min)")
    print(f"{'part':<44} {'value':>10}")
    print(f"{'FE runs (' + str(n) + ', ' + str(args.n_jobs) + ' processes), wall s':<44} {fe_wall:>10.1f}")
    print(f"{'FE runs, worker CPU s (sum)':<44} {cpu:>10.1f}")
    print(f"{'FE run, CPU ms each':<44} {1000 * cpu / n:>10.1f}")
    print(f"{'FE stage with the cores to itself, s (CPU/n)':<44} {cpu / args.n_jobs:>10.1f}")
    print(f"{'Pearson (read chunks, Eq. 16), s':<44} {pearson_wall:>10.2f}")
    print(f"{'sensitivity and SVD at 2 points, s':<44} {sens_wall:>10.2f}")
    print(f"{'total wall, s':<44} {total:>10.1f}   target <= {TARGET_SECONDS:.0f} for N = 10,000 "
          f"({'met' if total <= TARGET_SECONDS else 'missed'})")
    if failed:
        print(f"{failed} FE runs failed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
