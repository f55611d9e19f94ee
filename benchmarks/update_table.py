"""Markdown table of repeated updating runs (issue 4's results table).

    python -m flows.update --run-id table-gradient --trainer gradient --repeats 5
    ...                                                 # likewise sao, pso, --strategy conventional
    python -m benchmarks.update_table runs/table-gradient runs/table-sao ...

One row per seed: iterations, FE runs (and how many of them the polish made),
final overall error (Eq. 6b) and each
parameter's absolute error against the known truth.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def rows(run_dir: Path) -> list[str]:
    summary = json.loads((run_dir / "summary.json").read_text())
    runs = summary.get("runs", [summary])
    out = []
    for r in runs:
        pe = r.get("parameter_errors", {})
        label = f"{r['strategy']} / {r['trainer']}"
        polish = r.get("polish", {}).get("n", "-")
        out.append(
            f"| {label} | {r['seed']} | {r['iterations']} | {r['fe_evaluations']} | {polish} | "
            f"{r['overall_error']:.4%} | "
            + " | ".join(f"{v:.3f}" for v in pe.values())
            + f" | {max(pe.values()):.3f} |"
        )
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.update_table",
                                     description="Print the markdown table of docs/results/update-results.md from run folders.")
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (runs/<run-id>, --repeats folders)")
    dirs = parser.parse_args(sys.argv[1:] if argv is None else argv).runs
    print("| strategy / trainer | seed | iterations | FE runs | of which polish | overall error | "
          + " | ".join(f"\\|err\\| alpha_{i}" for i in range(1, 7)) + " | largest |")
    print("|" + "---|" * 14)
    for d in dirs:
        for line in rows(d):
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
