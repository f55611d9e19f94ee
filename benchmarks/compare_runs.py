"""Two runs of the same update side by side: FE runs, Jacobians, parameters and their largest difference.

    python -m benchmarks.compare_runs RUN_FOLDER_A RUN_FOLDER_B [...more pairs]

Reads each run's ``summary.json`` (and the FE log for the count of FE runs made) and prints a markdown table:
the results of a change that must not alter them (issue 41's levers) next to the code before it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tasks.io.summary import read_summary


def _summary(folder: Path) -> dict:
    """The run's summary in the current shape: a run of code from before the summary's schema compares too."""
    return read_summary(folder / "summary.json")


def compare(a: Path, b: Path) -> str:
    sa, sb = _summary(a), _summary(b)
    pa, pb = sa["parameters"], sb["parameters"]
    diff = max(abs(pa[k] - pb[k]) for k in pa)
    keys = ("fe_evaluations", "jacobians", "rounds", "converged", "overall_error")
    rows = [f"| {a.name} | " + " | ".join(str(sa.get(k)) for k in keys) + " | "
            + ", ".join(f"{pa[k]:.10f}" for k in sorted(pa)) + " | |",
            f"| {b.name} | " + " | ".join(str(sb.get(k)) for k in keys) + " | "
            + ", ".join(f"{pb[k]:.10f}" for k in sorted(pb)) + f" | {diff:.1e} |"]
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.compare_runs", description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders in pairs: before after [before after ...]")
    args = parser.parse_args(argv).runs
    if len(args) < 2 or len(args) % 2:
        parser.error("give pairs of run folders")
    print("| run | FE runs | Jacobians | rounds | converged | overall error | parameters | largest difference |")
    print("|---|---|---|---|---|---|---|---|")
    for a, b in zip(args[::2], args[1::2]):
        print(compare(a, b))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
