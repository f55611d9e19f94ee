"""The report's sections: figures and tables from a loaded run (plain functions).

Each function takes the data of :mod:`tasks.report.data` and the report
folder, writes its PNG files there and returns a :class:`~tasks.report.html.Section`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from tasks.intervals import cost_against_update
from tasks.report.figures.closure import plot_candidates, plot_closure_frf
from tasks.report.figures.errors import plot_error_overall, plot_error_per_sensor, plot_training_time
from tasks.report.figures.frf import plot_frf_overview, plot_frf_zoom, plot_residual_maps
from tasks.report.figures.intervals import plot_intervals
from tasks.report.figures.parameters import plot_distributions, plot_parameters, plot_samples
from tasks.report.figures.repeats import plot_error_trends, plot_repeats_error, plot_repeats_parameters
from tasks.report.data import RepeatsData, RunData, best_so_far, residual_frame
from tasks.report.frf import dense_frequencies, dense_frf, zoom_windows
from tasks.report.html import Section

__all__ = [
    "frf_section",
    "errors_section",
    "parameters_section",
    "training_section",
    "stages_section",
    "closure_section",
    "repeats_section",
    "intervals_section",
    "run_intro",
]

CACHE = "cache"


def _bounds(data: RunData) -> tuple[float, float]:
    return float(data.config.get("lower", -1.0)), float(data.config.get("upper", 1.0))


def run_intro(data: RunData) -> list[str]:
    cfg = data.config
    sid, _, err = data.best()
    done = "finished" if data.summary else "not finished (no summary.json): this report shows the finished stages"
    lines = [
        f"Run folder {data.root} ({done}).",
        f"Strategy {cfg.get('strategy', '?')}, trainer {cfg.get('trainer', '?')}, seed {cfg.get('seed', '?')}, "
        f"model {cfg.get('model', '?')}, measured data {cfg.get('measured', '?')}.",
        f"{int(data.errors['iteration'].max())} {'cycles' if cfg.get('strategy') == 'hybrid' else 'iterations'} and "
        f"{(data.summary or {}).get('fe_evaluations', len(data.samples))} FE runs"
        + (f" ({data.summary['jacobians']} with their exact Jacobian, {data.summary['fe_equivalents']:g} FE-run "
           f"equivalents, {data.summary['rounds']} rounds)" if (data.summary or {}).get("jacobians") else "")
        + (f" ({len(data.polish)} of them in the polish stage)" if data.polish is not None else "") + "; "
        f"reported overall error {err:.3%}" + (f" (sample {sid})" if sid >= 0 else "") + ".",
    ]
    lowest = (data.summary or {}).get("lowest_error")
    if lowest:
        lines.append(f"Reported parameters: {data.summary.get('parameters_source')}; the FE run with the lowest "
                     f"overall error (sample {lowest.get('sample_id')}, {lowest['overall_error']:.3%}) is kept in "
                     "summary.json's lowest_error (measured at efdea20, git show 0cbca1f:docs/estimators.md: the optimum is the better estimate on noisy "
                     "data).")
    if data.summary:
        lines.append(f"Stop reason: {data.summary.get('stop_reason', '?')}; "
                     f"{'converged' if data.summary.get('converged') else 'not converged'}; "
                     f"wall time {data.summary.get('wall_seconds', float('nan')):.1f} s.")
    return lines


# -- Figure 3 -------------------------------------------------------------------------------------
def frf_section(data: RunData, out: Path, label: str = "") -> Section:
    """Measured vs. initial (alpha = 0) vs. updated FRF amplitude, dense in frequency; residual maps."""
    names = data.names
    _, updated, _ = data.best()
    initial = np.zeros(len(names))
    freqs = data.frequencies
    grid = dense_frequencies(freqs)
    windows = zoom_windows(freqs)
    model_name = data.config.get("model", "three_plate")
    dense = dense_frf(data.model, model_name, {"initial": initial, "updated": updated}, grid,
                      out / CACHE / "frf_dense.parquet", channels=_run_channels(data), names=names)
    info = data.manifest.get("measured_data") or {}
    labels = None if info.get("form", "legacy").startswith("legacy") else {
        j + 1: f"{c['label']} ({c['sensor']} / {c['excitation']})" for j, c in enumerate(info["channels"])}
    fig1 = plot_frf_overview(dense, data.measured, out / "frf_overview.png", windows, labels=labels)
    fig2 = plot_frf_zoom(dense, data.measured, out / "frf_zoom.png", windows, labels=labels)
    # Residuals of both models at the measured points (the dense grid holds them exactly).
    maps, rows = {}, []
    for name in ("initial", "updated"):
        c = dense.loc[dense["curve"] == name, ["frequency_hz", "sensor", "amplitude"]]
        merged = data.measured.assign(key=data.measured["frequency_hz"].round(6)).merge(
            c.assign(key=c["frequency_hz"].round(6)).drop(columns="frequency_hz"),
            on=["key", "sensor"], suffixes=("", "_model")).drop(columns="key")
        merged["residual"] = (merged["amplitude_model"] - merged["amplitude"]) / merged["amplitude"]
        maps[f"{name} model"] = merged[["frequency_hz", "sensor", "residual"]]
        per_sensor = merged.assign(a=merged["residual"].abs()).groupby("sensor")["a"].mean()
        rows.append({"model": name, "overall error (Eq. 6b)": f"{merged['residual'].abs().mean():.3%}",
                     **{f"sensor {s}": f"{v:.2%}" for s, v in per_sensor.items()}})
    fig3 = plot_residual_maps(maps, out / "residual_map.png",
                              "Relative residual (|Z| - u) / u at the measured points, percent")
    truth = data.true_parameters
    params = pd.DataFrame({"parameter": names, "initial": initial, "updated": updated})
    if truth is not None and len(truth) == len(names):
        params["true"] = truth
        params["|updated - true|"] = np.abs(updated - truth)
    return Section(
        title=f"Measured and model FRF amplitudes (Figure 3){label}",
        paragraphs=[f"The initial model has every stiffness factor at 0; the updated model has the reported "
                    f"parameters. Curves are FE runs on {grid.size} frequencies (cached in "
                    f"{CACHE}/frf_dense.parquet); squares are the {freqs.size} measured frequencies."],
        tables=[("Parameters", params), ("Errors at the measured points", pd.DataFrame(rows))],
        figures=[(fig1, "FRF amplitude per sensor over the band"),
                 (fig2, "Each measurement window per sensor"),
                 (fig3, "Where each model misses the measurement")],
    )


def _run_channels(data: RunData):
    """The run's measured channels on the model (None: its sensors under its default excitation)."""
    info = data.manifest.get("measured_data")
    if not info or info["form"].startswith("legacy"):  # the model's own FRF: no model needed to say so
        return None
    from tasks.report.lines import channels_of_run

    return channels_of_run(data.manifest, data.model)


# -- Figures 4, 5 ---------------------------------------------------------------------------------
def errors_section(data: RunData, out: Path) -> Section:
    best = best_so_far(data)
    threshold = data.config.get("threshold")
    fig1 = plot_error_overall(data.errors, best, out / "error_overall.png", threshold, data.polish)
    fig2 = plot_error_per_sensor(best, out / "error_per_sensor.png")
    table = best[["iteration", "fe_evaluations", "sample_id", "overall_error"]].copy()
    table["overall_error"] = table["overall_error"].map(lambda v: f"{v:.3%}")
    notes = []
    if data.config.get("strategy") == "conventional":
        notes.append("Conventional strategy (Section 3.4): iteration 1 is the uniform FE sample that trains one "
                     "MRGP; iteration 2 is the FE run of its best prediction.")
    polish = (data.summary or {}).get("polish")
    if isinstance(polish, dict):
        notes.append(f"Polish stage (least squares on the FE model after the MRGP loop): {polish.get('status')}, "
                     f"{polish.get('n')} FE runs, overall error {polish.get('error_before', float('nan')):.3%} -> "
                     f"{polish.get('error_after', float('nan')):.3%}; drawn after the last iteration.")
    failed = int((data.errors["status"] != "ok").sum())
    if failed:
        notes.append(f"{failed} FE runs failed and are left out.")
    return Section(
        title="Error per iteration (Figures 4 and 5)",
        notes=notes,
        tables=[("Best sample so far", table)],
        figures=[(fig1, "Overall error (Eq. 6b) of every FE sample and the best so far"),
                 (fig2, "Per-sensor error (Eq. 15) of the best sample so far")],
    )


# -- Figures 6-8 ----------------------------------------------------------------------------------
def parameters_section(data: RunData, out: Path) -> Section:
    names, truth, bounds = data.names, data.true_parameters, _bounds(data)
    best = best_so_far(data)
    _, reported, reported_error = data.best()
    later = reported_error < best["overall_error"].iloc[-1] and not np.allclose(reported, best[names].iloc[-1])
    figs = [(plot_samples(data.samples, names, out / "samples.png", truth, data.polish, bounds),
             "Sampled parameters per iteration (Figure 6)"),
            (plot_parameters(best, data.distributions, names, out / "parameters.png", truth, bounds,
                             final=reported if later else None,
                             final_label="polish" if data.polish is not None else "last stage"),
             "Parameter trajectories (Figure 7)")]
    if len(data.distributions):
        figs.append((plot_distributions(data.distributions, names, out / "distributions.png", truth, bounds),
                     "Sampling distributions (Figure 8)"))
    tables = []
    if len(data.distributions):
        last = data.distributions[data.distributions["iteration"] == data.distributions["iteration"].max()]
        tables.append((f"Sampling distribution of iteration {int(last['iteration'].iloc[0])}",
                       last[["parameter", "kind", "mean", "std"]]))
    if data.polish is not None:
        cols = [c for c in ["sample_id", "overall_error", *names, "source"] if c in data.polish.columns]
        tables.append(("Polish-stage points", data.polish[cols].head(30)))
    return Section(title="Parameters (Figures 6-8)", tables=tables, figures=figs,
                   paragraphs=["Dashed red lines are the true values (manifest true_parameters)."]
                   if truth is not None else ["The true parameters are not known for this data."])


def intervals_section(data: RunData, out: Path) -> Section | None:
    """Marginal posteriors, 95 % intervals and correlations from ``summary.json`` (:mod:`tasks.intervals`)."""
    s = data.summary or {}
    if "intervals" not in s:
        return None
    d, names = s["interval_details"], list(s["intervals"])

    def arr(values):
        return np.array([np.inf if v is None else v for v in values], float)

    est = arr(d["estimate"][n] for n in names)
    std = arr(d["std"][n] for n in names)
    low = arr(s["intervals"][n]["lower95"] if s["intervals"][n]["lower95"] is not None else -np.inf for n in names)
    high = arr(s["intervals"][n]["upper95"] for n in names)
    corr = np.array([[np.nan if v is None else v for v in row] for row in d["correlation"]], float)
    truth = data.true_parameters
    samples = weights = laplace_std = None
    path = (None if s.get("interval_method", "laplace") == "laplace" else
            Path(data.root) / f"iteration={s.get('iterations')}" / "stage=intervals" / "posterior.parquet")
    if path is not None and path.exists():  # a sampled posterior: draw its marginals
        post = pd.read_parquet(path)
        samples, weights = post[names].to_numpy(), post["weight"].to_numpy()
        laplace_std = arr(d["laplace"]["std"][n] for n in names) if "laplace" in d else None
    fig = plot_intervals(names, est, std, low, high, corr, out / "intervals.png", truth, _bounds(data),
                         samples=samples, weights=weights, laplace_std=laplace_std)
    conditional = s.get("interval_status") == "conditional"
    level = "conditional" if conditional else "95 %"
    table = pd.DataFrame({"parameter": names, "estimate": est, f"low ({level})": low, f"high ({level})": high,
                          "std": std})
    if truth is not None:
        table["true"] = truth
        table["contains truth"] = (low <= truth) & (truth <= high)
    cost = s.get("interval_cost", {})
    spent = f"{cost.get('jacobians', '?')} exact Jacobian(s), each with its FRF"
    if cost.get("fe_runs"):
        spent += f" and {cost['fe_runs']} FE runs"
    against = cost_against_update(s)
    if against:
        spent += f" ({against})"
    how = ("Laplace (Gauss-Newton) approximation at the least-squares optimum of the log amplitudes"
           if s.get("interval_method", "laplace") == "laplace" else
           f"{s['interval_method'].capitalize()} of the posterior on the FE model around the least-squares "
           "optimum (bars: the weighted samples; dashed: the Laplace approximation it replaced)")
    paragraphs = [f"{how}, noise {100 * s['noise_sigma']:.3g} % ({d['noise_source']}; {d['distribution']} quantile "
                  f"{d['quantile']:.3f}); cost {spent}. The coverage of these intervals is checked in "
                  "docs/results/coverage-n500.md and docs/results/posterior.md.", *([f"Why: {d['method_reason']}"] if "method_reason" in d
                                                               else []), *d["flags"]]
    if conditional:  # the model does not explain the data: not 95 % intervals (flows.summary.interval_status)
        paragraphs.insert(0, f"These intervals are {s['conditional_on']}. They would be 95 % intervals if the model "
                             "were right; here they understate the uncertainty and are not 95 % intervals.")
    return Section(title="How sure: parameter intervals", paragraphs=paragraphs,
                   tables=[("Intervals conditional on the model" if conditional else "95 % intervals", table)],
                   figures=[(fig, "Marginal posteriors and correlations")])


# -- Figure 9 -------------------------------------------------------------------------------------
def _training_series(training: pd.DataFrame) -> pd.DataFrame:
    t = training.copy()
    t["trainer"] = np.where(t["stage"] == "train", t["trainer"], t["trainer"] + " (rerun)")
    return t


def training_section(data: RunData, out: Path) -> Section | None:
    if data.training.empty:
        return None
    t = _training_series(data.training)
    fig = plot_training_time(t, out / "training_time.png", "trainer")
    total = t.groupby("trainer")["seconds"].sum().map(lambda v: f"{v:.2f}")
    return Section(title="MRGP training time (Figure 9)",
                   tables=[("Total training time (s)", total.reset_index())],
                   figures=[(fig, "Training time per iteration from each train stage's _stage.json")])


# -- inventory -------------------------------------------------------------------------------------
def stages_section(data: RunData) -> Section:
    inv = data.stages
    rows = []
    for k, part in inv.groupby("iteration"):
        rows.append({"iteration": int(k),
                     "finished stages": ", ".join(part.loc[part["finished"], "stage"]),
                     "unfinished": ", ".join(part.loc[~part["finished"], "stage"]) or "-"})
    return Section(title="Stages in the run folder", notes=list(data.notes), tables=[("Stages", pd.DataFrame(rows))])


# -- close the loop ---------------------------------------------------------------------------------
#: Candidate scores, in order of preference; the first one every candidate has is drawn.
SCORE_KEYS = ("explained", "linear_explained", "score", "delta_ebic", "delta_bic", "linear_delta_ebic", "bic",
              "aic", "explained_fraction", "error_after", "error")


def _effect_label(entry: dict) -> str:
    parts = [str(entry[k]) for k in ("type", "name", "effect", "kind") if entry.get(k) is not None][:1]
    loc = entry.get("location")
    if loc is not None and not (isinstance(loc, float) and np.isnan(loc)):
        parts.append(f"@ {json.dumps(loc) if isinstance(loc, (list, dict)) else loc}")
    return " ".join(parts)


def _candidate_table(candidates) -> tuple[pd.DataFrame, str] | None:
    """Candidates (a list of dicts, best first) as a table with a ``label`` and the score column to draw."""
    if not isinstance(candidates, list) or not candidates:
        return None
    rows = [c if isinstance(c, dict) else {"candidate": c} for c in candidates]
    df = pd.DataFrame(rows)
    numeric = [k for k in df.columns if pd.api.types.is_numeric_dtype(df[k]) and df[k].dtype != bool
               and k != "rank"]
    if {"explained", "linear_explained"} <= set(numeric):
        # tasks.closure: a full FE fit's share of the residual where checked, the linearised screen's elsewhere.
        df["explained (light: linearised only)"] = df["explained"].fillna(df["linear_explained"])
        df["_light"] = df["explained"].isna()
        numeric.insert(0, "explained (light: linearised only)")
    complete = [k for k in numeric if df[k].notna().all()]
    score = next((k for k in ("explained (light: linearised only)", *SCORE_KEYS) if k in complete),
                 complete[0] if complete else None)
    if score is None:
        return None
    df["label"] = [_effect_label(r) or f"candidate {i + 1}" for i, r in enumerate(rows)]
    return df, score


def _pct(v):
    return f"{100 * v:.3g}%" if isinstance(v, (int, float)) else ("-" if v is None else str(v))


def closure_section(data: RunData, out: Path) -> Section | None:
    """Residual maps before/after and the ranked candidate effects, when ``closure.json`` exists.

    Reads the ``closure.json`` of :mod:`tasks.closure` (``effect``, ``error_before/after``,
    ``parameters_before/after``, ``candidates``, ``residual_tables``) and tolerates other
    spellings of the residual tables (records, column lists, file names).
    """
    c = data.closure
    if c is None:
        return None
    folder = Path(c.get("_folder", data.root))
    figs, tables, paragraphs, notes = [], [], [], []
    effect = c.get("effect")
    if c.get("decision"):
        paragraphs.append(f"Decision: {c['decision']}.")
    row = {"effect added": _effect_label(effect) if isinstance(effect, dict) else ("none" if effect is None
                                                                                     else str(effect))}
    if isinstance(effect, dict) and "value" in effect:
        value = effect["value"]
        row["value"] = (f"{value:.4g} {effect.get('unit', '')}".strip() if isinstance(value, (int, float))
                        else json.dumps(value))
    row.update({"overall error before": _pct(c.get("error_before")), "after": _pct(c.get("error_after"))})
    if "noise_floor" in c:
        row["noise floor"] = _pct(c["noise_floor"])
    for key in ("n_candidates", "fe_solves"):
        if key in c:
            row[key.replace("_", " ")] = c[key]
    tables.append(("Close-the-loop result", pd.DataFrame([row])))
    psb, psa = c.get("per_sensor_error_before"), c.get("per_sensor_error_after")
    if isinstance(psb, dict) and isinstance(psa, dict):
        keys = list(dict.fromkeys([*psb, *psa]))
        tables.append(("Per-sensor error (Eq. 15)", pd.DataFrame(
            {"sensor": keys, "before": [_pct(psb.get(k)) for k in keys], "after": [_pct(psa.get(k)) for k in keys]})))
    columns = {name: c.get(key) for name, key in (("updating run", "parameters_run"), ("before", "parameters_before"),
                                                  ("after", "parameters_after")) if isinstance(c.get(key), dict)}
    if columns:
        keys = list(dict.fromkeys(k for d in columns.values() for k in d))
        tables.append(("Parameters", pd.DataFrame({"parameter": keys, **{
            name: [d.get(k, "-") for k in keys] for name, d in columns.items()}})))
    freqs = data.frequencies
    maps = {}
    for when in ("before", "after"):
        options = [c.get(f"residuals_{when}"), c.get(f"residual_{when}"), c.get(f"residual_table_{when}"),
                   (c.get("residual_tables") or {}).get(when), (c.get("residuals") or {}).get(when)
                   if isinstance(c.get("residuals"), dict) else None,
                   f"residual_{when}.parquet", f"residuals_{when}.parquet"]
        for obj in options:
            df = residual_frame(obj, folder, freqs)
            if df is not None:
                maps[when] = df
                break
    if maps:
        figs.append((plot_residual_maps(maps, out / "closure_residuals.png",
                                        "Residual before and after adding the effect, percent (one scale)",
                                        shared_scale=True),
                     "Residual map before and after"))
    else:
        notes.append("closure.json names no residual table this report can read.")
    frf_path = folder / (c.get("frf_table") or "frf_closure.parquet")
    if frf_path.is_file():
        figs.append((plot_closure_frf(pd.read_parquet(frf_path), out / "closure_frf.png",
                                      f"FRF: alpha only and with the added effects ({c.get('verdict', '')})"),
                     "FRF of the final extended model beside the alpha-only one"))
    if c.get("verdict"):
        paragraphs.append(f"Verdict: {c['verdict']}. " + "; ".join(
            f"{e['step']}. {e['type']} at {e['location']} = {e['value']:.4g} {e['unit']} "
            f"({e['explained']:.0%} of the residual then"
            + (f", evidence {e['evidence']:.0%}" if "evidence" in e else "") + ")"
            + "".join(f" or {r['type']} at {r['location']} = {r['value']:.4g} {r['unit']} "
                      f"(evidence {r['evidence']:.0%})" for r in e.get("rivals", []))
            for e in c.get("effects", []) if isinstance(e, dict))
            + (" The data cannot tell an added effect from its rivals: none of them is a finding."
               if c["verdict"] == "ambiguous" else ""))
    ranked = _candidate_table(c.get("candidates"))
    if ranked is not None:
        df, score = ranked
        chosen = _effect_label(effect) if isinstance(effect, dict) else None
        figs.append((plot_candidates(df, out / "closure_candidates.png", score, chosen),
                     f"Candidate effects ranked (bars: {score})"))
        shown = df.drop(columns=[k for k in ("label", "_light", "explained (light: linearised only)")
                                 if k in df.columns]).head(15)
        for col in shown.columns:  # nested values (locations as dicts) as text
            if shown[col].map(lambda v: isinstance(v, (dict, list))).any():
                shown[col] = shown[col].map(lambda v: json.dumps(v) if isinstance(v, (dict, list)) else v)
        tables.append((f"Candidates (top {len(shown)} of {c.get('n_candidates', len(df))})", shown))
    return Section(title="Close the loop: residual and missing effect", paragraphs=paragraphs, notes=notes,
                   tables=tables, figures=figs)


# -- Figures 10-13 ---------------------------------------------------------------------------------
def repeats_section(rep: RepeatsData, out: Path) -> list[Section]:
    """Statistics of repeated runs (Figures 10-11, or 12-13 for the conventional strategy)."""
    runs = rep.runs
    first = rep.first
    strategy = first.config.get("strategy", "adaptive")
    conventional = strategy == "conventional"
    fig_err, fig_par = ("12", "13") if conventional else ("10", "11")
    names = first.names
    rows = []
    trends = {}
    for i, r in sorted(runs.items()):
        sid, alpha, err = r.best()
        label = f"seed {r.config.get('seed', i)}"
        rows.append({"label": label, "repeat": i, "overall_error": err, **dict(zip(names, alpha)),
                     "fe_evaluations": int((r.summary or {}).get("fe_evaluations", len(r.samples))),
                     "iterations": int(r.errors["iteration"].max()),
                     "converged": bool(r.summary.get("converged")) if r.summary else None})
        trends[label] = best_so_far(r)
    table = pd.DataFrame(rows)
    threshold = first.config.get("threshold")
    truth = first.true_parameters
    bounds = _bounds(first)
    what = "conventional approach" if conventional else "adaptive MRGP"
    f1 = plot_repeats_error(table, out / "repeats_error.png", threshold,
                            f"Final overall error of each run, {what} (Figure {fig_err})")
    f2 = plot_repeats_parameters(table, names, out / "repeats_parameters.png", truth,
                                 f"Identified parameters of each run, {what} (Figure {fig_par})", bounds)
    f3 = plot_error_trends(trends, out / "repeats_error_trend.png", threshold)
    figs = [(f1, f"Overall error per run (Figure {fig_err})"), (f2, f"Identified parameters (Figure {fig_par})"),
            (f3, "Best error so far against FE runs, per run")]
    training = [r.training.assign(run=f"seed {r.config.get('seed', i)}") for i, r in sorted(runs.items())
                if not r.training.empty]
    if training:
        t = pd.concat(training, ignore_index=True)
        t = t[t["stage"] == "train"]
        figs.append((plot_training_time(t, out / "training_time.png", "run"),
                     "MRGP training time per iteration and run (Figure 9)"))
    shown = table.copy()
    shown["overall_error"] = shown["overall_error"].map(lambda v: f"{v:.3%}")
    tables = [("Runs", shown)]
    stats = (rep.summary or {}).get("repeats")
    if stats:
        srows = [{"quantity": "overall error", **stats["overall_error"]}]
        srows += [{"quantity": k, **v} for k, v in stats.get("parameters", {}).items()]
        srows += [{"quantity": f"|{k} - true|", **v} for k, v in stats.get("parameter_errors", {}).items()]
        srows += [{"quantity": k, **stats[k]} for k in ("fe_evaluations", "iterations") if k in stats]
        tables.append((f"Statistics over {stats.get('n', len(runs))} runs (summary.json); success rate "
                       f"{stats.get('success_rate', float('nan')):.0%}", pd.DataFrame(srows)))
    notes = list(rep.errors)
    if rep.summary is None:
        notes.append("No summary.json at the top: the repeats are not all finished; statistics are of the "
                      "readable runs.")
    return [Section(title=f"Repeated runs (Figures {fig_err}-{fig_par})", notes=notes, tables=tables, figures=figs)]

