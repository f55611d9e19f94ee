"""The report of an updating run: ``python -m flows.report --run-id ID``.

Reads only the run folder (its Parquet tables and JSON records; the FE model
is run for two parameter vectors to draw the dense FRF curves, cached as
Parquet), writes PNG figures and one self-contained HTML page to
``<run folder>/report/`` and prints the page's path.

Examples::

    python -m flows.report --run-id pso-3
    python -m flows.report --run-id repeats-5                 # a --repeats run: Figures 10-13
    python -m flows.report --run-id my-run --runs-dir /runs --out /tmp/my-report

What it draws depends on the folder: every run, of any strategy, gets Figures 3-9 (FRF,
errors, samples, parameters; sampling distributions and training time where the
paper's loop made them) and, for a model with
a mesh, the mesh by segment with its sensors and excitation and the updated factors
as colours (a model given as matrices gets one line saying why not); a ``--repeats``
folder gets the statistics of Figures 10-13 and the FRF of its best run; a
run with ``closure.json`` gets the residual maps before/after and the
ranked candidate effects. Stage folders the report does not know are listed.
"""

from __future__ import annotations

from flows import environment  # noqa: F401  (first: the environment Prefect starts in)

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from prefect import flow, task  # noqa: E402
from prefect.cache_policies import NO_CACHE  # noqa: E402

from flows.config import REPO, ConfigError  # noqa: E402
from flows.problem import load_model  # noqa: E402
from tasks.report import sections as sec  # noqa: E402
from tasks.report.data import ReportError, is_repeats_folder, load_repeats, load_run  # noqa: E402
from tasks.report.html import write_page  # noqa: E402
from tasks.report.lines import lines_section  # noqa: E402
from tasks.report.mesh import mesh_section  # noqa: E402

__all__ = ["report_flow", "main", "REPORT_DIR", "PAGE"]

REPORT_DIR = "report"
PAGE = "report.html"


# Thin tasks: each wraps one plain function of tasks.report.
load_run_task = task(load_run, name="load-run", cache_policy=NO_CACHE)
load_repeats_task = task(load_repeats, name="load-repeats", cache_policy=NO_CACHE)
frf_task = task(sec.frf_section, name="frf-figures", cache_policy=NO_CACHE)
errors_task = task(sec.errors_section, name="error-figures", cache_policy=NO_CACHE)
parameters_task = task(sec.parameters_section, name="parameter-figures", cache_policy=NO_CACHE)
training_task = task(sec.training_section, name="training-figure", cache_policy=NO_CACHE)
closure_task = task(sec.closure_section, name="closure-figures", cache_policy=NO_CACHE)
mesh_task = task(mesh_section, name="mesh-figures", cache_policy=NO_CACHE)
lines_task = task(lines_section, name="line-selection-figure", cache_policy=NO_CACHE)
intervals_task = task(sec.intervals_section, name="interval-figures", cache_policy=NO_CACHE)
repeats_task = task(sec.repeats_section, name="repeats-figures", cache_policy=NO_CACHE)
page_task = task(write_page, name="html-page", cache_policy=NO_CACHE)


@flow(name="run-report", flow_run_name="report-{run_root}", log_prints=True)
def report_flow(run_root: str, out_dir: str | None = None) -> str:
    """Draw the report of the run at ``run_root``; returns the HTML page's path."""
    root = Path(run_root)
    out = Path(out_dir) if out_dir else root / REPORT_DIR
    if not root.is_dir():
        raise ReportError(f"{root}: no such run folder")
    out.mkdir(parents=True, exist_ok=True)
    if is_repeats_folder(root):
        rep = load_repeats_task(root)
        best = rep.best_run()
        best.model = _run_model(best)
        parts = [*repeats_task(rep, out),
                 frf_task(best, out, f" - best run, {best.root.name}"), mesh_task(best, out)]
        closure = closure_task(best, out)
        title = f"Run report: {root.name} ({len(rep.runs)} repeats)"
        intro = [f"Repeats folder {root}; each repeat's own report: python -m flows.report --run-id "
                 f"{root.name}/repeat=<i>."] + sec.run_intro(best)[1:2]
    else:
        data = load_run_task(root)
        data.model = _run_model(data)
        parts = [frf_task(data, out), lines_task(data, out), mesh_task(data, out), errors_task(data, out),
                 parameters_task(data, out),
                 intervals_task(data, out), training_task(data, out)]
        closure = closure_task(data, out)
        parts.append(sec.stages_section(data))
        title = f"Run report: {root.name}"
        intro = sec.run_intro(data)
    if closure is not None:
        parts.insert(1, closure)
    page = page_task(out / PAGE, title, [p for p in parts if p is not None], intro)
    print(f"report written to {page}")
    return str(page)


def _run_model(data):
    """The run's model, read once from its manifest's model (and checked against the run's checksum)."""
    model, ref = load_model(data.config.get("model", "three_plate"))
    stored = data.manifest.get("model_checksum")
    if stored is not None and stored != ref.checksum:
        data.notes.append(f"the model file {ref.path} changed since the run (checksum differs): the FRF curves and "
                          "mesh pictures show the file as it is now")
    return model


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m flows.report",
        description="Figures (PNG) and one self-contained HTML page from an updating run's folder: "
                    "FRF measured vs. initial vs. updated, errors, samples, parameters, sampling distributions, "
                    "training time; statistics of --repeats runs; close-the-loop results when present.")
    p.add_argument("--run-id", required=True, metavar="ID",
                   help="run folder name under --runs-dir (a repeat of a --repeats run: ID/repeat=0)")
    p.add_argument("--runs-dir", default="runs", metavar="PATH", help="where run folders are (default runs)")
    p.add_argument("--out", metavar="PATH", help="report folder (default <run folder>/report)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    runs = Path(args.runs_dir)
    runs = runs if runs.is_absolute() else REPO / runs
    root = runs / args.run_id
    if not root.is_dir():
        print(f"error: {root}: no such run folder", file=sys.stderr)
        return 2
    try:
        page = report_flow(str(root), args.out)
    except (ReportError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
