"""The documentation's run pictures, redrawn from fresh runs with the code of this checkout.

``nice -n 10 python -m benchmarks.doc_figures`` (3 min CPU; 16 min wall on 2 cores at load 8-14) runs, in a
temporary runs folder, the commands the docs show and copies the figures their reports draw:

1. ``python -m flows.update`` (the main job) and ``python -m flows.report``: ``docs/figures/report-frf.png`` (the
   report's FRF overview: measured points, initial and updated model) and ``docs/figures/report-error.png`` (the
   overall error of every FE run);
2. ``python -m flows.update --measured data/benchmark/hammer.uff`` and its report: ``docs/figures/hammer-frf.png``
   (the hammer test's channels, initial and updated model) and ``docs/figures/hammer-lines.png`` (the lines used,
   those left out for coherence, the coherence);
3. ``python -m flows.update --measured data/cases/three_plate_effects/point_mass.csv --close-loop --noise 0.005``:
   ``docs/figures/closure-residuals.png`` (the residual per sensor before and after the closure adds the point mass);
4. ``python -m flows.correlation --samples 10000``: ``docs/figures/correlation.png`` (Pearson correlation of each
   parameter with each sensor's amplitude; ``--correlation-samples`` sets N; 10,000 FE runs: 6 CPU-min, 13 min wall).

``--only report hammer closure`` redraws some of them. Each command's printed summary goes to
``<runs>/<name>.log``; the runs folder is kept when ``--keep`` is given.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs" / "figures"

#: name: (update options, or None for the correlation analysis, [(file the run folder holds, docs figure)]).
FIGURES = {
    "report": ([], [("report/frf_overview.png", "report-frf.png"), ("report/error_overall.png", "report-error.png")]),
    "hammer": (["--measured", "data/benchmark/hammer.uff"],
               [("report/frf_overview.png", "hammer-frf.png"), ("report/line_selection.png", "hammer-lines.png")]),
    "closure": (["--measured", "data/cases/three_plate_effects/point_mass.csv", "--close-loop", "--noise", "0.005"],
                [("closure/residuals.png", "closure-residuals.png")]),
    "correlation": (None, [("correlation/correlation.png", "correlation.png")]),
}


def _run(args: list[str], log: Path) -> None:
    with log.open("a") as out:
        out.write("$ python -m " + " ".join(args) + "\n")
        out.flush()
        proc = subprocess.run([sys.executable, "-m", *args], cwd=REPO, stdout=out, stderr=subprocess.STDOUT)
    if proc.returncode != 0:
        raise SystemExit(f"python -m {' '.join(args)} exited {proc.returncode}; see {log}")


def draw(name: str, runs: Path, correlation_samples: int = 10000) -> list[Path]:
    """Run ``name``'s update and report in ``runs`` and copy its figures into docs/figures/; the paths written."""
    options, figures = FIGURES[name]
    run_id, log = f"docs-{name}", runs / f"{name}.log"
    t0 = time.perf_counter()
    if options is None:
        _run(["flows.correlation", "--samples", str(correlation_samples), "--runs-dir", str(runs), "--run-id", run_id],
             log)
    else:
        _run(["flows.update", "--runs-dir", str(runs), "--run-id", run_id, *options], log)
        _run(["flows.report", "--runs-dir", str(runs), "--run-id", run_id], log)
    written = []
    for source, target in figures:
        src = runs / run_id / source
        if not src.exists():
            raise SystemExit(f"{name}: the run folder has no {source}; see {log}")
        shutil.copyfile(src, DOCS / target)
        written.append(DOCS / target)
    print(f"{name}: {', '.join(p.name for p in written)} ({time.perf_counter() - t0:.0f} s)")
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.doc_figures", description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=sorted(FIGURES), default=sorted(FIGURES),
                        help="redraw only these (default: all)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary runs folder (printed)")
    parser.add_argument("--correlation-samples", type=int, default=10000, metavar="N",
                        help="FE samples of the correlation analysis (default 10000, the paper's)")
    args = parser.parse_args(argv)
    runs = Path(tempfile.mkdtemp(prefix="doc-figures-"))
    try:
        for name in args.only:
            draw(name, runs, args.correlation_samples)
    finally:
        if args.keep:
            print(f"runs kept in {runs}")
        else:
            shutil.rmtree(runs, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
