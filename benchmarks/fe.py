"""Speed of the FE core on the three-plate benchmark (3510 DOFs, 12 frequencies, 6 sensors).

Run on one core, as the issue asks::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.fe

It times assembly (mesh, element matrices, segment matrices), one FRF
evaluation with the Krylov solver, and the reference direct solve (one complex
sparse LU per frequency) in the same run, on the same parameter vectors, and
reports the largest relative difference between the two.
"""

from __future__ import annotations

import argparse
import os
import platform

# One core: set before numpy loads its BLAS.
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from benchmarks.timing import median_time  # noqa: E402
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate  # noqa: E402

TARGET_RATIO = 0.1
TARGET_RDIFF = 1e-8


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=21, help="timed repetitions per case (default 21)")
    parser.add_argument("--samples", type=int, default=10, help="random parameter vectors besides the actual one")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    alphas = [ALPHA_ACTUAL] + [rng.uniform(-0.95, 1.0, 6) for _ in range(args.samples)]

    t_assembly = median_time(lambda: three_plate.__wrapped__(), max(3, args.repeats // 4))
    model = three_plate()

    t_fast, t_direct, worst = [], [], 0.0
    for alpha in alphas:
        t_fast.append(median_time(lambda: model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ), args.repeats))
        t_direct.append(
            median_time(lambda: model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ, method="direct"), max(3, args.repeats // 4))
        )
        fast = model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ)
        ref = model.frf(alpha, MEASUREMENT_FREQUENCIES_HZ, method="direct")
        worst = max(worst, float(np.max(np.abs(fast - ref) / np.abs(ref))))

    fast, direct = float(np.median(t_fast)), float(np.median(t_direct))
    ratio = fast / direct
    print(f"FE benchmark: {model.n_dofs} free DOFs, {len(MEASUREMENT_FREQUENCIES_HZ)} frequencies, "
          f"{model.n_sensors} sensors, {len(alphas)} parameter vectors, {args.repeats} repeats")
    print(f"machine: {platform.processor() or platform.machine()}, numpy {np.__version__}, "
          f"OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}")
    print()
    print(f"| {'metric':<44} | {'value':>12} | {'target':>12} | {'':4} |")
    print(f"|{'-' * 46}|{'-' * 14}|{'-' * 14}|{'-' * 6}|")
    rows = [
        ("assembly (mesh, elements, segment matrices)", f"{t_assembly * 1e3:.1f} ms", "", ""),
        ("FRF, direct complex LU per frequency", f"{direct * 1e3:.1f} ms", "reference", ""),
        ("FRF, Krylov projection (median)", f"{fast * 1e3:.1f} ms", "", ""),
        ("Krylov / direct time", f"{ratio:.3f}", f"<= {TARGET_RATIO}", "pass" if ratio <= TARGET_RATIO else "FAIL"),
        ("largest relative difference to direct", f"{worst:.1e}", f"<= {TARGET_RDIFF:.0e}",
         "pass" if worst <= TARGET_RDIFF else "FAIL"),
    ]
    for name, value, target, verdict in rows:
        print(f"| {name:<44} | {value:>12} | {target:>12} | {verdict:4} |")
    return 0 if ratio <= TARGET_RATIO and worst <= TARGET_RDIFF else 1


if __name__ == "__main__":
    raise SystemExit(main())
