"""Modal updating against FRF updating on the same measured FRFs (issue 31): the benchmark's hammer test.

    nice -n 10 python -m benchmarks.modal_vs_frf            # a few minutes on 2 busy cores

Both read ``data/benchmark/hammer.uff`` (impact at test node 5, 6 accelerometers, 0-400 Hz, 1 % noise,
from the SPEC's actual structure) with ``data/benchmark/model.toml``:

* FRF: ``python -m flows.update`` with its defaults (the hybrid: Gauss-Newton on the complex FRF residual,
  its check, intervals);
* modal: ``python -m flows.update --identify-modes 20-400`` (sdypy-EMA LSCF/LSFD: 2 modes at 6 test DOFs,
  then the modal update from ``--starts`` points (default 1, the nominal model), uncertainties estimated from the residual);
* modal, paper loop: the same with ``--strategy paper`` (the MRGP over the modal residuals, then the local fit
  from its best FE run).

``--only frf,modal,paper`` runs some of the three (default all).

Prints and writes (``<out>/modal_vs_frf.json``) per path: FE runs (FRF: the run's FE evaluations, and its
FE-run equivalents counting the Jacobians' cost; modal: eigen-solves and Nelson Jacobians), wall time, the
largest |error| of the factors, how many true factors lie in their 95 % intervals.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import time
from pathlib import Path

import numpy as np

from fe_core.benchmark import ALPHA_ACTUAL
from flows import update
from tasks.io.summary import read_summary

MODEL = "data/benchmark/model.toml"
HAMMER = "data/benchmark/hammer.uff"
TRUE = "--true-parameters=" + ",".join(str(v) for v in ALPHA_ACTUAL)


def _run(argv) -> float:
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = update.main(argv)
    if code != 0:
        raise SystemExit(f"flows.update {' '.join(argv)} exited {code}")
    return time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.modal_vs_frf")
    p.add_argument("--runs-dir", default="runs/modal-vs-frf")
    p.add_argument("--starts", type=int, default=1, help="local fits of the modal update (default 1: the nominal "
                                                         "start, as the FRF hybrid's first cycle)")
    p.add_argument("--only", default="frf,modal,paper", help="paths to run, of frf, modal, paper (default all)")
    args = p.parse_args(argv)
    only = set(args.only.split(","))
    stamp = str(int(time.time()))
    root = Path(args.runs_dir)
    out = {}
    if "frf" in only:
        out["frf"] = _frf(root, stamp)
    for key, extra in (("modal", []), ("paper", ["--strategy", "paper"])):
        if key in only:
            out["modal" if key == "modal" else "modal_paper"] = _modal(root, f"{key}-{stamp}", args.starts, extra)
    print(json.dumps(out, indent=1))
    root.mkdir(parents=True, exist_ok=True)
    (root / "modal_vs_frf.json").write_text(json.dumps(out, indent=1))
    return 0


def _frf(root: Path, stamp: str) -> dict:
    seconds = _run(["--model", MODEL, "--measured", HAMMER, "--runs-dir", str(root), "--run-id", f"frf-{stamp}"])
    s = read_summary(root / f"frf-{stamp}")
    est = np.array(list(s["parameters"].values()))
    frf = {"wall_seconds_cli": seconds, "fe_evaluations": s["fe_evaluations"], "jacobians": s["jacobians"],
           "fe_equivalents": s["fe_equivalents"], "wall_seconds": s["wall_seconds"],
           "max_abs_error": float(np.max(np.abs(est - ALPHA_ACTUAL)))}
    if s.get("intervals"):
        frf["inside95"] = _inside(s)
    return frf


def _inside(s: dict) -> int:
    """How many of the actual alpha lie inside the summary's 95 % intervals (an unbounded side: no bound)."""
    iv = [s["intervals"][n] for n in s["parameters"]]
    lo = np.array([-np.inf if v["lower95"] is None else v["lower95"] for v in iv])
    hi = np.array([np.inf if v["upper95"] is None else v["upper95"] for v in iv])
    return int(np.sum((lo <= ALPHA_ACTUAL) & (ALPHA_ACTUAL <= hi)))


def _modal(root: Path, run_id: str, starts: int, extra: list) -> dict:
    seconds = _run(["--model", MODEL, "--measured", HAMMER, "--identify-modes", "20-400", "--starts", str(starts),
                    "--runs-dir", str(root), "--run-id", run_id, TRUE, *extra])
    m = read_summary(root / run_id)
    theta = np.array(list(m["parameters"].values()))
    row = {"wall_seconds_cli": seconds, "fe_runs": m["fe_evaluations"], "jacobians": m["jacobians"],
           "seconds_update": m["seconds"], "seconds_identification": m["seconds_identification"],
           "max_abs_error": float(np.max(np.abs(theta - ALPHA_ACTUAL))),
           "inside95": _inside(m), "modes": len(m["paired_modes"])}
    if "paper_loop" in m:
        pl = m["paper_loop"]
        row.update(paper_fe_runs=pl["fe_runs"], paper_iterations=pl["iterations"], paper_seconds=pl["seconds"],
                   paper_reason=pl["reason"], fit_fe_runs=m["fe_runs_fit"])
        row["seconds_update"] += pl["seconds"]
    return row


if __name__ == "__main__":
    raise SystemExit(main())
