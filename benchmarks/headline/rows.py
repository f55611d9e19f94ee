"""The rows of the README's ``## Headline results`` table: each row's commands and how its figures are read.

A row is what the README shows (``what``, ``details``), the commands that measure it (run from the
repository's root, ``{out}`` replaced by the row's folder under ``runs/headline/``), and ``summarise``,
which reads what the commands wrote and returns the README's result cell and the figures behind it. Truths
come from the data's own files (``truth.json``, the SPEC's actual alpha), never from the run.

Where the page a row links to measured more than a headline rerun can afford (over ~20 min), the row's
``note`` says what the rerun leaves out; the README then shows the rerun's figures.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks.headline import parse as P

REPO = Path(__file__).resolve().parents[2]
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@dataclass
class Row:
    """One headline row. ``commands``: (argv after ``python -m``, extra environment) pairs."""

    key: str
    what: str
    details: str
    commands: list[tuple[list[str], dict]]
    summarise: Callable[[Path, str, list[dict]], tuple[str, dict]]   # (folder, log, timings) -> (cell, figures)
    note: str = ""
    env: dict = field(default_factory=dict)


def _alpha_actual() -> np.ndarray:
    from fe_core.benchmark import ALPHA_ACTUAL

    return np.asarray(ALPHA_ACTUAL, float)


def _truth(path: str, key: str) -> np.ndarray:
    return np.asarray(json.loads((REPO / path).read_text())[key], float)


def _run_figures(folder: Path, truth: np.ndarray) -> dict:
    s = P.summary(folder)
    est = P.estimate(s)
    bounds = P.intervals(s)
    return {"fe_runs": P.fe_runs(s), "jacobians": s.get("jacobians"), "fe_equivalents": s.get("fe_equivalents"),
            "cycles": s.get("iterations"), "converged": s.get("converged"),
            "max_error": float(np.max(np.abs(est - truth))), "estimate": np.round(est, 5).tolist(),
            "truth": truth.tolist(), "inside95": P.covered(bounds, truth), "of": int(truth.size),
            "interval_status": s.get("interval_status"), "overall_error": s.get("overall_error"),
            "flow_wall_s": s.get("wall_seconds", s.get("seconds"))}


# -- the main job ----------------------------------------------------------------------------------------------
def _main(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    f = _run_figures(out / "main", _alpha_actual())
    t = timing[0]
    text = (f"every alpha within {P.up(f['max_error'])} of the truth after {f['fe_runs']} FE runs "
            f"({f['jacobians']} with their exact Jacobians); {t['wall_s']:.0f} s wall, {t['cpu_s']:.0f} s CPU "
            "for the command, Prefect's start-up included")
    return text, f


# -- the random truths --------------------------------------------------------------------------------------
def _suite(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    import pandas as pd

    runs = pd.read_csv(out / "suite-runs.csv")
    fig = {}
    for (noise, method), g in runs.groupby(["noise", "method"]):
        reached = g["fe_to_floor"].notna()
        fig[f"{method} {noise:g}"] = {"truths": len(g), "floor": int(reached.sum()), "success": int(g["success"].sum()),
                                      "misses": g.loc[~reached, "truth"].tolist(),
                                      "fe_to_floor_median": P.median(g["fe_to_floor"].tolist()),
                                      "equivalents_to_floor_median": P.median(g["fe_equivalents_to_floor"].tolist())}
    d0, d1 = fig["default 0"], fig["default 0.01"]
    f0, f1 = fig["dfo-ls-nominal 0"], fig["dfo-ls-nominal 0.01"]
    text = (f"default {d0['floor']}/{d0['truths']} and {d1['floor']}/{d1['truths']} at the floor, median "
            f"{d0['fe_to_floor_median']:g} / {d1['fe_to_floor_median']:g} FE runs "
            f"({d0['equivalents_to_floor_median']:.1f} / {d1['equivalents_to_floor_median']:.1f} FE-run eq.); DFO-LS "
            f"from nominal {f0['floor']}/{f0['truths']} and {f1['floor']}/{f1['truths']}, median "
            f"{f0['fe_to_floor_median']:g} / {f1['fe_to_floor_median']:g}")
    return text, fig


def _compare_figures(out: Path) -> dict:
    import pandas as pd

    runs = pd.read_csv(out / "compare-runs.csv")
    fig = {}
    for (ds, method), g in runs.groupby(["dataset", "method"]):
        fig[f"{ds} {method}"] = {"runs": len(g), "to_floor": int(g["runs_to_floor"].notna().sum()),
                                 "to_1pct": int(g["runs_to_1pct"].notna().sum()),
                                 "runs_to_floor_median": P.median(g["runs_to_floor"].tolist()),
                                 "runs_to_1pct": g["runs_to_1pct"].dropna().astype(int).tolist(),
                                 "fe_runs_used": g["fe_runs"].astype(int).tolist(),
                                 "largest_parameter_error_median": P.median(g["largest_parameter_error"].tolist())}
    return fig


def _compare(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    fig = _compare_figures(out)
    b, f = fig["benchmark default"], fig["far-noisy default"]
    db, df = fig["benchmark dfo-ls-nominal"], fig["far-noisy dfo-ls-nominal"]
    text = (f"default {b['runs_to_floor_median']:g} / {f['runs_to_floor_median']:g} FE runs to the noise floor "
            f"(median; floor reached in {b['to_floor']}/{b['runs']} and {f['to_floor']}/{f['runs']} seeds); DFO-LS "
            f"from nominal {db['runs_to_floor_median']:g} / {df['runs_to_floor_median']:g}")
    return text, fig


def _paper(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    fig = _compare_figures(out)
    rows = [v for k, v in fig.items() if k.startswith("benchmark paper-")]
    n = sum(r["runs"] for r in rows)
    hit = sum(r["to_1pct"] for r in rows)
    floor = sum(r["to_floor"] for r in rows)
    to1 = [x for r in rows for x in r["runs_to_1pct"]]
    used = [x for r in rows for x in r["fe_runs_used"]]
    text = (f"below 1 % in {hit} of {n} runs (5 seeds x 3 trainers) after {P.span(to1)} FE runs, {P.span(used)} "
            f"used; the noise floor in {floor} of {n}")
    return text, fig


# -- examples and measured files ------------------------------------------------------------------------------
def _bracket(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    f = _run_figures(out / "bracket", _truth("data/examples/bracket/truth.json", "alpha"))
    t = timing[0]
    status = f["interval_status"] or "-"
    text = (f"every factor within {P.up(f['max_error'])} of the truth (intervals {status}, {f['inside95']}/{f['of']} "
            f"cover it), {f['fe_runs']} FE runs, {t['wall_s'] / 60:.1f} min wall on 2 cores")
    return text, f


def _hammer(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    truth = _alpha_actual()
    f = _run_figures(out / "hammer", truth)
    m = re.search(r"lines: all: (\d+) of (\d+) lines", log)
    f["lines"] = int(m.group(1)) if m else None
    t = timing[0]
    f["peak_rss_gb"] = t["peak_rss_gb"]
    f["noise"] = (P.summary(out / "hammer").get("noise_model") or {}).get("source")
    others = {k: _run_figures(out / k, truth) for k in ("hammer-roving", "hammer-mobility")}
    f.update({k.replace("-", "_"): v for k, v in others.items()})

    def said(g: dict) -> str:
        state = "converged" if g["converged"] else "NOT converged"
        return (f"{state}, {g['fe_runs']} FE runs, every alpha within {P.up(g['max_error'])}, "
                f"{g['inside95']}/{g['of']} inside their 95 % intervals ({g['interval_status'] or 'intervals'})")

    text = (f"{f['lines']} lines with coherence (noise from {f['noise']}): {said(f)}; {t['wall_s']:.0f} s wall, peak "
            f"memory {t['peak_rss_gb']:.2f} GB. Roving hammer (6 references): {said(others['hammer-roving'])}. "
            f"As mobility: {said(others['hammer-mobility'])}")
    return text, f


def _coverage(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    import pandas as pd

    runs = pd.read_csv(out / "coverage-runs.csv")
    rates = {f"{noise:g} {est}": float(g["covered"].mean()) for (noise, est), g in runs.groupby(["noise", "estimator"])}
    m = re.search(r"(\d+) of (\d+) intervals cover the truth \(([\d.]+)\)", log)
    sets = re.search(r"roving hammer \(.*?\), (\d+) data sets", log)
    fig = {"coverage": rates, "data_sets_per_level": int(runs["dataset"].nunique()),
           "roving": {"covered": int(m.group(1)), "of": int(m.group(2)), "rate": float(m.group(3)),
                      "sets": int(sets.group(1))}}
    r = fig["roving"]
    text = (f"coverage {P.span(rates.values(), '{:.3f}')} (0.5 % and 1 % noise, noise estimated or given); roving "
            f"hammer (6 references) {r['rate']:.3f} on {r['sets']} sets; conditional, not 95 %, when the residual is "
            "structure")
    return text, fig


def _modal_coverage(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    fig = json.loads((out / "modal-coverage" / "modal_coverage_spec.json").read_text())
    e, o = fig["ema"], fig["oma"]
    text = (f"EMA {e['inside']}/{e['of']}, OMA (unscaled, one mode missing) {o['inside']}/{o['of']} factors inside "
            f"their 95 % intervals (the same noise draws through the model linearised at the truth: "
            f"{e['linearised_inside']} and {o['linearised_inside']})")
    return text, fig


def _modal_vs_frf(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    fig = json.loads((out / "modal-vs-frf" / "modal_vs_frf.json").read_text())
    frf, gn, pl = fig["frf"], fig["modal"], fig["modal_paper"]
    text = (f"modes identified (sdypy-EMA), then Gauss-Newton: {gn['fe_runs']} eigen-solves + {gn['jacobians']} "
            f"Jacobians, {gn['wall_seconds_cli']:.1f} s; the paper's loop: {pl['paper_fe_runs']} + {pl['fit_fe_runs']} "
            f"eigen-solves, {pl['wall_seconds_cli']:.0f} s; largest error {P.up(gn['max_abs_error'])} / "
            f"{P.up(pl['max_abs_error'])}, {gn['inside95']}/6 and {pl['inside95']}/6 inside; the FRF update: "
            f"{P.up(frf['max_abs_error'])}, {frf['wall_seconds_cli']:.1f} s")
    return text, fig


# -- closing the loop ---------------------------------------------------------------------------------------------
def _closure(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    rows = P.json_tail(log)
    effects = [r for r in rows if r.get("true_effect")]
    clean = [r for r in rows if not r.get("true_effect")]
    right = [r for r in effects if r["verdict"] == "explained" and r.get("location_error", {}).get("same")]
    fig = {"effects": len(effects), "explained_at_true_place": len(right),
           "value_errors": [r.get("value_error") for r in effects], "p_after": [r["p_after"] for r in effects],
           "clean": len(clean), "clean_noise": sum(r["verdict"] == "noise" for r in clean),
           "cpu_s": [round(r["cpu_seconds"], 1) for r in rows]}
    worst = max((v for v in fig["value_errors"] if v is not None), default=float("nan"))
    text = (f"{len(right)}/{len(effects)} explained at their node or place, value within {P.percent(worst)}, "
            f"chi-square p after {P.span(fig['p_after'], '{:.2f}')} (noise); clean data: noise in "
            f"{fig['clean_noise']}/{fig['clean']}")
    return text, fig


FAR_OFF_MASSES = ["cantilever-1.9%", "benchmark-2%", "cantilever-5%", "cantilever-10%", "benchmark-5%"]


def _far_off(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    rows = P.markdown_rows(log, "case")
    explained = sum(r["verdict"] == "explained" for r in rows)
    at_node = sum(r["node right"] == "True" for r in rows)
    sizes = [P.number(r["size error"]) for r in rows]
    runs = [int(P.number(r["update FE runs"])) for r in rows]
    fig = {"rows": rows}
    text = (f"{explained}/{len(rows)} explained, the mass at its node in {at_node}/{len(rows)}, size within "
            f"{P.percent(max(sizes))}; {P.span(runs)} FE runs")
    return text, fig


LARGE = ["mass-19%", "patch-50%", "patch-90%", "spring-rigid", "mass-25%"]


def _large(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    rows = {r["case"]: r for r in P.markdown_rows(log, "case")}
    fitted = [rows[c] for c in LARGE[:4]]
    ok = sum(r["verdict"] == "explained" and r["right place"] == "True" for r in fitted)
    sizes = [P.number(r["size error"]) / 100 for r in fitted if r["size error"] != "-"]
    flagged = rows["mass-25%"]["at a bound"] != "-" and rows["mass-25%"]["added"] == "-"
    text = (f"{ok}/4 explained at the true place, sized within {P.percent(max(sizes))} (joint fit from several "
            f"starts); a 25 % mass {'flagged at its bound, not added' if flagged else 'NOT flagged at its bound'}")
    return text, {"rows": list(rows.values())}


# -- CalculiX -----------------------------------------------------------------------------------------------------
def _route_a(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    f = _run_figures(out / "panel", _truth("data/examples/shell_panel/truth.json", "parameters"))
    draws = [re.findall(r"True|False", m) for m in re.findall(r"covers \[([^\]]*)\]", log)]
    f["draws"] = len(draws)
    f["draws_covered"] = sum(x == "True" for d in draws for x in d)
    f["draw_intervals"] = sum(len(d) for d in draws)
    text = (f"{f['fe_runs']} FE runs, {f['cycles']} cycle(s); every factor within {P.up(f['max_error'])} of the truth; "
            f"{f['inside95']}/{f['of']} inside their 95 % intervals ({f['interval_status']}; "
            f"{f['draws_covered']}/{f['draw_intervals']} over {f['draws']} noise draws)")
    return text, f


def _route_b(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    f = _run_figures(out / "thick", _truth("data/examples/shell_thickness/truth.json", "parameters"))
    m = f["of"]
    f["ccx_runs"] = f["fe_runs"] + (f["jacobians"] or 0) * m   # a forward-difference Jacobian: m more runs
    text = (f"{f['ccx_runs']} ccx runs ({f['fe_runs']} FE runs, {f['jacobians']} forward-difference Jacobians), "
            f"{f['cycles']} cycle(s); every factor within {P.up(f['max_error'])} of the truth; {f['inside95']}/{m} "
            f"inside their 95 % intervals ({f['interval_status']}); {timing[0]['wall_s'] / 60:.1f} min wall")
    return text, f


# -- speed -----------------------------------------------------------------------------------------------------
def _speed(out: Path, log: str, timing: dict) -> tuple[str, dict]:
    ratio = float(re.search(r"\|\s*Krylov / direct time\s*\|\s*([\d.]+)", log).group(1))
    jac = P.markdown_rows((out / "jacobian.md").read_text(), "model")
    cost = {r["model"]: float(r["in FE runs"]) for r in jac}
    text = (f"Krylov FRF {1 / ratio:.0f}x faster than one LU per frequency; an exact Jacobian costs "
            f"{P.span(cost.values(), '{:.1f}')} FE runs")
    return text, {"krylov_over_direct": ratio, "jacobian_in_fe_runs": cost}


ROWS = [
    Row("main", "the main job (benchmark, noise-free)", "[strategies](docs/guide/strategies.md)",
        [(["flows.update", "--runs-dir", "{out}", "--run-id", "main"], {})], _main),
    Row("suite", "24 random truths in [-0.9, 0.9]^6, noise-free / 1 % noise, the plain command (budget 240 FE-run "
        "eq., cap 600 while still improving)", "[suite](docs/results/suite.md), "
        "[closure far off](docs/guide/closure-far-off.md)",
        [(["benchmarks.suite", "--budget", "240", "--methods", "default", "dfo-ls-nominal", "--noise", "0", "0.01",
           "--out", "{out}/suite"], {})], _suite,
        note="The default and DFO-LS from nominal only (the suite page also runs the paper's loop, DFO-LS from "
             "random starts and least squares)."),
    Row("compare", "benchmark (noise-free) / far truth with 1 % noise, 5 seeds",
        "[compare-default](docs/results/compare-default.md)",
        [(["benchmarks.compare", "--seeds", "0", "1", "2", "3", "4", "--datasets", "benchmark", "far-noisy",
           "--methods", "default", "dfo-ls-nominal", "--out", "{out}/compare"], {})], _compare,
        note="The default and DFO-LS from nominal only (the page also runs the paper's loop per trainer, DFO-LS "
             "from random starts and least squares)."),
    Row("paper", "the paper's loop (`--strategy adaptive --no-polish`) on the benchmark",
        "[compare-paper](docs/results/compare-paper.md)",
        [(["benchmarks.compare", "--seeds", "0", "1", "2", "3", "4", "--datasets", "benchmark", "--methods",
           "paper-gradient", "paper-sao", "paper-pso", "--out", "{out}/compare"], {})], _paper,
        note="The benchmark data set only (the page adds the far truth with 1 % noise)."),
    Row("bracket", "L-bracket, tet10, measured on an independent finer mesh, 1 % noise",
        "[model files](docs/guide/model-files.md)",
        [(["flows.update", "--model", "data/examples/bracket/model.toml", "--measured",
           "data/examples/bracket/measured.csv", "--runs-dir", "{out}", "--run-id", "bracket"], {})], _bracket),
    Row("hammer", "simulated hammer test (exact model, 1 % response noise, a sensor floor, 0.2 % force noise), "
        "UFF58 accelerance with coherence; the roving-hammer and mobility examples",
        "[measured formats](docs/guide/measured-formats.md), [noise model](docs/guide/noise-model.md)",
        [(["flows.update", "--measured", "data/benchmark/hammer.uff", "--runs-dir", "{out}", "--run-id", "hammer"],
          {}),
         (["flows.update", "--model", "data/examples/hammer_tests/model_roving.toml", "--measured",
           "data/examples/hammer_tests/roving.uff", "--runs-dir", "{out}", "--run-id", "hammer-roving"], {}),
         (["flows.update", "--measured", "data/examples/hammer_tests/mobility.uff", "--runs-dir", "{out}",
           "--run-id", "hammer-mobility"], {})], _hammer),
    Row("coverage", "95 % intervals, 200 data sets per noise level",
        "[coverage](docs/results/coverage-n500.md), [measured data](docs/guide/measured-data.md)",
        [(["benchmarks.coverage", "--n", "200", "--noise", "0.005", "0.01", "--seed", "23", "--out",
           "{out}/coverage"], {}),
         (["benchmarks.roving_coverage", "--no-cost"], {})], _coverage,
        note="200 data sets per noise level where the coverage page has 500 (about 25 min more)."),
    Row("modal-coverage", "modal data: the benchmark's 6 modes at 18 test nodes, 0.2 % / 2 % noise, 20 sets",
        "[modal data](docs/guide/modal-data.md)",
        [(["benchmarks.modal_coverage", "--out", "{out}/modal-coverage"], {})], _modal_coverage),
    Row("modal-vs-frf", "the hammer test's FRFs as modes: Gauss-Newton (Nelson) vs the paper's MRGP loop, and the "
        "FRF update", "[modal data](docs/guide/modal-data.md), [modal results](docs/results/modal.md)",
        [(["benchmarks.modal_vs_frf", "--runs-dir", "{out}/modal-vs-frf"], {})], _modal_vs_frf),
    Row("closure", "closing the loop on 5 single missing effects (benchmark, 0.5 % noise) and 5 clean sets",
        "[closure](docs/guide/closure.md)", [(["benchmarks.closure"], ONE_THREAD)], _closure),
    Row("far-off", "undeclared point mass of 1.9-10 % of the mass, then `--close-loop`",
        "[closure far off](docs/guide/closure-far-off.md)",
        [(["benchmarks.closure_far_off", "--only", *FAR_OFF_MASSES], {})], _far_off),
    Row("large", "large effects, scikit-fem data: 19 % point mass, -50 % / -90 % damaged patch, 5e7 N/m mount",
        "[closure](docs/guide/closure.md)", [(["benchmarks.closure_large", *LARGE], ONE_THREAD)], _large),
    Row("route-a", "CalculiX S8R shell panel (`data/examples/shell_panel`), 4 segment moduli from ccx's matrices "
        "(route A), suspended 20x20 model, data from ccx's 40x40 mesh, 1 % noise",
        "[solver decks](docs/guide/solver-decks.md)",
        [(["flows.update", "--model", "data/examples/shell_panel/model.toml", "--measured",
           "data/examples/shell_panel/measured.csv", "--runs-dir", "{out}", "--run-id", "panel"], {}),
         (["benchmarks.shell_panel_coverage", "--draws", "10"], {})], _route_a),
    Row("route-b", "CalculiX shell thicknesses, ccx as a black box (route B, forward-difference Jacobians), "
        "suspended 20x20 panel, data solved directly on the same mesh",
        "[solver decks](docs/guide/solver-decks.md)",
        [(["flows.update", "--model", "data/examples/shell_thickness/model.toml", "--measured",
           "data/examples/shell_thickness/measured.csv", "--runs-dir", "{out}", "--run-id", "thick"], {})],
        _route_b),
    Row("speed", "FRF and exact Jacobian", "[performance](docs/results/performance.md)",
        [(["benchmarks.fe"], ONE_THREAD), (["benchmarks.jacobian", "--out", "{out}/jacobian.md"], {})], _speed),
]
