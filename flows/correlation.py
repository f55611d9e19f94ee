"""Which parameters can the sensors identify? ``python -m flows.correlation --samples N``.

Section 3.5 of Zhou & Tang: N FE runs with parameters uniform in the search
box, the Pearson correlation (Eq. 16) of every parameter with every sensor's
FRF amplitude at every measured frequency (Figures 14-19), and, beside it, a
local identifiability summary: the singular values of the normalised
sensitivity ``d log|Z| / d alpha`` at reference points (alpha = 0, the true
or updated parameters when known), which say which parameters, or
combinations of them, these sensors and frequencies can pin down.

FE runs go in parallel (joblib, loky processes) in chunks written to Parquet
as they finish; running the same command again resumes, and a larger
``--samples`` reuses the finished chunks.

Examples::

    python -m flows.correlation --samples 10000                      # the paper's size, benchmark model
    python -m flows.correlation --samples 2000 --run-id pso-3        # frequencies and updated point of a run
    python -m flows.correlation --samples 10000 --n-jobs 2 --seed 1

Output: ``runs/<run-id>/correlation/`` (``correlation-seed<seed>`` by
default), with ``correlation.html`` (printed at the end).
"""

from __future__ import annotations

from flows import environment  # noqa: F401  (first: the environment Prefect starts in)

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from joblib import Parallel, delayed  # noqa: E402
from prefect import flow, task  # noqa: E402
from prefect.cache_policies import NO_CACHE  # noqa: E402

from flows.config import REPO, ConfigError  # noqa: E402
from flows.problem import load_model  # noqa: E402
from tasks import correlation as corr  # noqa: E402
from tasks.report.figures import correlation as figures  # noqa: E402
from tasks.report.data import ReportError, load_run  # noqa: E402
from tasks.report.html import Section, write_page  # noqa: E402
from tasks.runstore import _parquet_bytes, atomic_write_bytes, atomic_write_json  # noqa: E402

__all__ = ["correlation_flow", "main", "SUBFOLDER"]

SUBFOLDER = "correlation"
CHUNK_SIZE = 50


def _logger():
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:
        import logging

        return logging.getLogger(__name__)


@task(name="fe-samples", cache_policy=NO_CACHE)
def fe_samples_task(folder: str, meta: dict, n_samples: int, n_jobs: int, ref, names: list[str]) -> dict:
    """FE runs of every chunk not on disk yet, in parallel; returns counts and seconds."""
    logger = _logger()
    path = Path(folder)
    todo = [c for c in corr.chunks_needed(n_samples, meta["chunk_size"]) if c not in corr.finished_chunks(path)]
    total = len(corr.chunks_needed(n_samples, meta["chunk_size"]))
    logger.info("%d of %d chunks of %d samples on disk; %d to run on %d processes", total - len(todo), total,
                meta["chunk_size"], len(todo), n_jobs)
    t0 = time.perf_counter()
    done = 0
    if todo:
        parallel = Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
        for _ in parallel(delayed(corr.evaluate_chunk)(folder, c, meta, ref, names) for c in todo):
            done += 1
            if done % max(1, len(todo) // 20) == 0 or done == len(todo):
                logger.info("FE chunks: %d/%d done (%.0f s)", done, len(todo), time.perf_counter() - t0)
    seconds = time.perf_counter() - t0
    return {"chunks_run": len(todo), "samples_run": len(todo) * meta["chunk_size"], "fe_seconds": seconds}


@task(name="pearson", cache_policy=NO_CACHE)
def pearson_task(folder: str, meta: dict, n_samples: int, names: list[str]) -> dict:
    X, A, columns, failed = corr.load_amplitudes(Path(folder), n_samples, meta, names)
    table = corr.correlation_table(X, A, columns, names)
    atomic_write_bytes(Path(folder) / "correlation.parquet", _parquet_bytes(table))
    return {"n_ok": int(X.shape[0]), "failed": failed}


@task(name="sensitivity", cache_policy=NO_CACHE)
def sensitivity_task(folder: str, meta: dict, references: dict, noise: float, tolerance: float, model):
    table, summary, results = corr.sensitivity_tables(model, {k: np.asarray(v) for k, v in references.items()},
                                                      meta["frequencies_hz"], noise, tolerance)
    atomic_write_bytes(Path(folder) / "sensitivity.parquet", _parquet_bytes(table))
    atomic_write_json(Path(folder) / "identifiability.json", _finite_or_none(summary))
    return summary, results


def _finite_or_none(obj):
    """JSON has no infinity: an unbounded standard deviation is written as null."""
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_none(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


@task(name="correlation-page", cache_policy=NO_CACHE)
def page_task(folder: str, meta: dict, n_samples: int, counts: dict, summary: dict, results: dict,
              fe_info: dict, names: list[str]) -> str:
    out = Path(folder)
    table = pd.read_parquet(out / "correlation.parquet")
    f1 = figures.plot_correlation(table, names, out / "correlation.png", counts["n_ok"])
    f2 = figures.plot_correlation_heatmap(table, names, out / "correlation_map.png")
    f3 = figures.plot_singular_values(results, out / "singular_values.png")
    strongest = (table.assign(a=table["rho"].abs(), b=table["rho_log"].abs()).groupby("parameter")
                 .agg(**{"max |rho|": ("a", "max"), "mean |rho|": ("a", "mean"),
                         "max |rho| with log|Z|": ("b", "max"), "mean |rho| with log|Z|": ("b", "mean")})
                 .reindex(names).reset_index())
    sections = [
        Section("Pearson correlation (Eq. 16, Figures 14-19)",
                paragraphs=[f"{counts['n_ok']:,} FE runs with every parameter uniform in "
                            f"[{meta['lower']}, {meta['upper']}] (seed {meta['seed']}); "
                            f"{counts['failed']} failed runs left out. Under independence |rho| stays below about "
                            f"{3 / math.sqrt(max(counts['n_ok'], 1)):.3f} (3 / sqrt(N))."],
                tables=[("Strength of each parameter's correlation over all 72 responses", strongest)],
                figures=[(f1, "Correlation per sensor and frequency"), (f2, "All coefficients in one map, with the amplitude and with its logarithm")]),
    ]
    for label, s in summary.items():
        rows = [{"parameter": k, "std at noise": v["std_at_noise"], "sensitivity norm": v["sensitivity_norm"],
                 "pinned down": "yes" if v["identifiable"] else "NO"} for k, v in s["parameters"].items()]
        dirs = [{"#": k, "singular value": v["singular_value"], "combination": v["combination"],
                 "std at noise": v["std_at_noise"]} for k, v in s["directions"].items()]
        sections.append(Section(
            f"Identifiability at {label}",
            paragraphs=[f"alpha = {np.round(s['alpha'], 3).tolist()}; condition number "
                        f"{s['condition_number']:.3g}. Linearised: with {s['noise']:.0%} independent relative "
                        f"noise on every amplitude, a parameter is pinned down when its standard deviation is "
                        f"at most {s['tolerance']:g}."] + s["verdict"],
            tables=[("Parameters", pd.DataFrame(rows)), ("Singular directions", pd.DataFrame(dirs))]))
    sections[-1].figures.append((f3, "Singular values and the linearised standard deviations"))
    intro = [f"Correlation analysis of model {meta['model']} at {len(meta['frequencies_hz'])} frequencies, "
             f"{n_samples:,} samples; FE stage {fe_info['fe_seconds']:.1f} s for {fe_info['samples_run']:,} new "
             f"runs."]
    return str(write_page(out / "correlation.html", "Correlation and identifiability", sections, intro))


@flow(name="correlation", flow_run_name="correlation-{n_samples}", log_prints=True)
def correlation_flow(folder: str, meta: dict, n_samples: int, n_jobs: int, references: dict,
                     noise: float = 0.01, tolerance: float = 0.05) -> dict:
    """N FE samples, Pearson correlation, sensitivity at the reference points, figures and page."""
    t0 = time.perf_counter()
    corr.prepare_folder(Path(folder), meta)
    model, ref = load_model(meta["model"])  # the model, read once for the whole analysis
    names = corr.parameter_names(meta, model)
    fe_info = fe_samples_task(folder, meta, n_samples, n_jobs, ref, names)
    counts = pearson_task(folder, meta, n_samples, names)
    summary, results = sensitivity_task(folder, meta, references, noise, tolerance, model)
    page = page_task(folder, meta, n_samples, counts, summary, results, fe_info, names)
    out = {"page": page, "n_samples": n_samples, **counts, **fe_info, "seconds": time.perf_counter() - t0}
    print(f"{n_samples} samples ({fe_info['samples_run']} FE runs now, {fe_info['fe_seconds']:.1f} s); "
          f"page {page}")
    for label, s in summary.items():
        print(f"identifiability at {label}:")
        for line in s["verdict"]:
            print(f"  {line}")
    return out


# -- command line -----------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m flows.correlation",
        description="Pearson correlation of each parameter with each sensor's FRF amplitude over N uniform FE "
                    "samples (Eq. 16, Figures 14-19), and the singular values of the normalised sensitivity "
                    "matrix: which parameters the sensors can identify.")
    p.add_argument("--samples", type=int, required=True, metavar="N", help="number of FE samples (paper: 10000)")
    p.add_argument("--run-id", metavar="ID",
                   help="folder under --runs-dir; if it is an updating run, its model, measured frequencies and "
                        "updated parameters are used (default correlation-seed<seed>, the benchmark)")
    p.add_argument("--runs-dir", default="runs", metavar="PATH")
    p.add_argument("--n-jobs", type=int, default=2, help="parallel FE processes, -1 = all cores (default 2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise", type=float, default=0.01,
                   help="relative amplitude noise for the identifiability verdict (default 0.01 = 1 %%)")
    p.add_argument("--tolerance", type=float, default=0.05,
                   help="largest standard deviation of a parameter that counts as pinned down (default 0.05)")
    return p


def _setup(args) -> tuple[Path, dict, dict]:
    from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ

    runs = Path(args.runs_dir)
    runs = runs if runs.is_absolute() else REPO / runs
    root = runs / (args.run_id or f"correlation-seed{args.seed}")
    model, lower, upper = "three_plate", -1.0, 1.0
    freqs = MEASUREMENT_FREQUENCIES_HZ
    references = {"alpha = 0": np.zeros(6)}
    if (root / "manifest.json").exists():  # an updating run: its model, frequencies and points
        data = load_run(root)
        cfg = data.config
        model, freqs = cfg.get("model", model), data.frequencies
        m = len(data.names)
        references = {"alpha = 0": np.zeros(m)}
        if data.true_parameters is not None:
            references["true alpha"] = data.true_parameters
        references[f"updated alpha ({root.name})"] = data.best()[1]
    else:
        references["benchmark actual alpha"] = ALPHA_ACTUAL
    meta = {"model": model, "frequencies_hz": [float(f) for f in freqs], "seed": args.seed,
            "chunk_size": CHUNK_SIZE, "n_parameters": len(next(iter(references.values()))),
            "lower": lower, "upper": upper}
    return root / SUBFOLDER, meta, {k: [float(x) for x in v] for k, v in references.items()}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.samples < 3:
        print("error: --samples must be at least 3", file=sys.stderr)
        return 2
    if args.n_jobs == 0 or args.n_jobs < -1:
        print(f"error: --n-jobs must be a positive number of processes or -1, got {args.n_jobs}", file=sys.stderr)
        return 2
    try:
        folder, meta, references = _setup(args)
        corr.prepare_folder(folder, meta)
    except (ReportError, corr.CorrelationError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result = correlation_flow(str(folder), meta, args.samples, args.n_jobs, references, args.noise, args.tolerance)
    print(json.dumps({k: v for k, v in result.items() if k != "page"}, default=float))
    print(result["page"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
