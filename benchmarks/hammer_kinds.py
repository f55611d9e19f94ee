"""One hammer test written as accelerance, mobility and receptance: the update must not care.

    python -m benchmarks.hammer_kinds              # three updates of data/benchmark/hammer.uff, ~1-2 min each
    python -m benchmarks.hammer_kinds --intervals  # with the 95 % intervals (minutes more per run)

``data/benchmark/hammer.uff`` (accelerance, :mod:`benchmarks.make.hammer`) is
read and written again as receptance and as mobility (UFF58, 12 significant
digits, the same channels, lines and coherence; :func:`tasks.io.measured.write_measured`);
each file is updated with the default settings and seed 0 (``python -m flows.update
--measured FILE``). The three runs must give the same parameters to 1e-6 and
recover the SPEC's actual alpha within 0.01. Prints the table of docs/guide/measured-formats.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
WORK = REPO / "runs" / "hammer-kinds"
KINDS = ("accelerance", "mobility", "receptance")
#: The issue's targets.
SAME_TOL = 1e-6
TRUTH_TOL = 0.01


def files() -> dict[str, Path]:
    """The test as each kind: the original accelerance file and two rewritten ones."""
    from tasks.io.measured import read_measured, write_measured

    WORK.mkdir(parents=True, exist_ok=True)
    measured = read_measured(HAMMER)
    out = {"accelerance": HAMMER}
    for kind in KINDS[1:]:
        out[kind] = write_measured(WORK / f"hammer_{kind}.uff", measured, kind=kind)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.hammer_kinds", description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", action="store_true", help="also compute the 95 %% intervals (slow)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from fe_core.benchmark import ALPHA_ACTUAL
    from flows import update
    from flows.config import load_config

    rows = {}
    for kind, path in files().items():
        run_id = f"hammer-kinds-{kind}-seed{args.seed}"
        config = load_config(None, measured=str(path), run_id=run_id, runs_dir=str(WORK / "runs"), seed=args.seed,
                             intervals=args.intervals, true_parameters=ALPHA_ACTUAL.tolist())
        t0, c0 = time.perf_counter(), time.process_time()
        summary = update.update_flow(config)
        rows[kind] = (summary, time.perf_counter() - t0, time.process_time() - c0)
    names = list(rows["accelerance"][0]["parameters"])
    ref = np.array([rows["accelerance"][0]["parameters"][n] for n in names])
    print(f"\nload average {os.getloadavg()[0]:.1f}; seed {args.seed}; data {HAMMER.relative_to(REPO)}")
    print(f"| file kind | {' | '.join(names)} | max |alpha - actual| | max |alpha - accelerance run| | "
          "overall error | FE runs | wall / CPU [s] |")
    print("|---" * (len(names) + 6) + "|")
    ok = True
    for kind, (summary, wall, cpu) in rows.items():
        alpha = np.array([summary["parameters"][n] for n in names])
        to_truth = float(np.max(np.abs(alpha - ALPHA_ACTUAL)))
        to_ref = float(np.max(np.abs(alpha - ref)))
        ok &= to_truth <= TRUTH_TOL and to_ref <= SAME_TOL
        print(f"| {kind} | {' | '.join(f'{a:.6f}' for a in alpha)} | {to_truth:.2e} | {to_ref:.1e} | "
              f"{summary['overall_error']:.4%} | {summary['fe_evaluations']} | {wall:.1f} / {cpu:.1f} |")
    print(f"actual alpha: {ALPHA_ACTUAL.tolist()}")
    print("targets met" if ok else "TARGETS NOT MET", f"(same to {SAME_TOL:g}, truth within {TRUTH_TOL:g})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
