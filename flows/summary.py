"""``summary.json`` of a run, from its run record, and its printout.

:func:`run_summary` takes the run's FE runs (:mod:`tasks.record`, the same for every strategy) and the
strategy's outcome (stop reason, convergence, the runs the result may be chosen from); :func:`finish_run`
adds the 95 % intervals (after a local least-squares stage: the hybrid's Gauss-Newton or the polish), writes
``model.vtu`` and ``summary.json``; :func:`print_summary` prints it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from tasks import record
from tasks.intervals import cost_against_update, intervals_task
from tasks.io.summary import SCHEMA_VERSION, entries_from_pairs
from tasks.model_vtu import model_vtu_task
from tasks.fe_runs import JACOBIAN_COST, is_large, run_cores
from tasks.runstore import RunStore, atomic_write_json

__all__ = ["run_summary", "finish_run", "repeat_summary", "print_summary", "interval_sentences",
           "report_least_squares_optimum", "LEAST_SQUARES_SOURCE", "interval_status", "CONDITIONAL_WORDS",
           "summary_interval_fields"]


def run_summary(problem, config, store: RunStore, iterations: int, outcome: dict, wall: float) -> dict:
    """The summary of one run: its best FE run (among ``outcome["candidates"]`` when given), what it spent,
    why it stopped."""
    runs = record.fe_runs(store, iterations)
    candidates = outcome.get("candidates")
    best = record.best_run(runs if candidates is None else runs[runs["sample_id"].isin(candidates)])
    used = record.spent(store, iterations)
    names, data = problem.names, problem.data
    summary = {
        "schema_version": SCHEMA_VERSION,
        "kind": "frf",
        "run_id": config.run_id if store.root.name == config.run_id else f"{config.run_id}/{store.root.name}",
        "parameters": {n: float(best[n]) for n in names},
        "overall_error": float(best["overall_error"]),
        "per_sensor_error": {f"sensor_{int(s)}": float(best[f"error_sensor_{j + 1}"])
                             for j, s in enumerate(data.sensors)},
        "fe_evaluations": int(used["evaluations"]),
        "jacobians": int(used["jacobians"]),
        "fe_equivalents": float(used["cost"]),
        "jacobian_cost": JACOBIAN_COST,
        "residual": data.residual,
        "rounds": int(used["rounds"]),
        "iterations": iterations,
        "converged": bool(outcome["converged"]),
        "stop_reason": outcome["stop_reason"],
        "trainer": config.trainer,
        "strategy": config.strategy,
        "seed": config.seed,
        "best_sample_id": int(best["sample_id"]),
        "wall_seconds": round(wall, 3),
        "run_folder": str(store.root),
    }
    if "polish" in outcome:
        summary["polish"] = outcome["polish"]
    for key in ("evidence", "own_error"):
        if key in outcome:
            summary[key] = outcome[key]
    if config.true_parameters is not None:
        truth = np.asarray(config.true_parameters, float)
        summary["true_parameters"] = {n: float(t) for n, t in zip(names, truth)}
        summary["parameter_errors"] = {n: float(abs(float(best[n]) - t)) for n, t in zip(names, truth)}
    return summary


def finish_run(problem, config, store: RunStore, iteration: int, summary: dict, intervals: bool = True) -> dict:
    """Intervals (when the strategy ends with a local least-squares stage, ``intervals``), model.vtu, then
    summary.json."""
    data = problem.data
    if intervals and config.intervals:
        summary.update(_interval_fields(problem, config, store, iteration, summary))
        if "intervals" in summary:
            summary.update(interval_status(summary))
        if summary.get("interval_status") == "conditional" and "method_reason" in summary["interval_details"]:
            details = summary["interval_details"]  # its reason speaks of a model that explains the data
            summary["interval_details"] = {**details, "method_reason": f"{details['method_reason'].split(':')[0]}: "
                                           f"{summary['conditional_on']}"}
        if data.residual == "amplitude":
            summary = report_least_squares_optimum(summary, data.sensors, config.true_parameters)
        else:  # the optimum of the log amplitudes ignores the phase this run's residual uses
            summary = {k: v for k, v in summary.items() if k != "estimate_errors"}
            summary["parameters_source"] = ("lowest Eq. (6b) error among the FE runs (complex residuals: the "
                                            "intervals' least-squares optimum uses the amplitudes only)")
    model_vtu_task(str(store.root), problem.model, summary["parameters"],  # <run>/model.vtu, before the summary
                   threads=run_cores(config) if is_large(problem.model) else 1)
    atomic_write_json(store.root / "summary.json", summary)
    return summary


#: ``summary["interval_status"]``: the intervals are the stated level's, or conditional on the model.
INTERVALS_AT_LEVEL, INTERVALS_CONDITIONAL = "95 %", "conditional"
CONDITIONAL_WORDS = "conditional on a model that does not explain the data"


def _hybrid_not_converged(summary: dict) -> bool:
    """A hybrid run that did not converge: its intervals are conditional, and so not worth a sampled posterior."""
    return summary.get("strategy") == "hybrid" and not summary.get("converged", True)


def interval_status(summary: dict) -> dict:
    """``interval_status`` and, when conditional, ``conditional_on`` (the reasons, in words).

    The intervals are 95 % intervals only if the model explains the data up to noise: they are
    conditional when the residual at their estimate is structure (``residual_check``) or when a hybrid
    run did not converge (its convergence is the same verdict at its own best point). A paper-loop run
    that stopped on its budget is not a reason by itself: its threshold is an error level, and the
    intervals' Gauss-Newton reaches the least-squares optimum where the residual check decides.
    """
    reasons = []
    check = summary.get("residual_check")
    if check and check["structured"]:
        reasons.append(f"the residual at the estimate is structure, not noise ({check['text']})")
    if _hybrid_not_converged(summary):
        reasons.append(f"the run did not converge ({summary.get('stop_reason', '')})")
    if not reasons:
        return {"interval_status": INTERVALS_AT_LEVEL}
    return {"interval_status": INTERVALS_CONDITIONAL, "conditional_on": f"{CONDITIONAL_WORDS}: {'; '.join(reasons)}"}


def summary_interval_fields(info: dict) -> dict:
    """The summary's interval fields from the intervals stage's record (:func:`tasks.intervals.intervals_task`):
    its ``[low, high]`` pairs become the summary's ``{"lower95", "upper95", "sd"}`` entries (``sd`` from
    ``interval_details["std"]``), the other fields are taken as they are."""
    fields = {k: info[k] for k in ("intervals", "covariance", "interval_method", "noise_sigma", "interval_details",
                                   "interval_cost", "estimate_errors", "residual_check", "noise_model") if k in info}
    fields["intervals"] = entries_from_pairs(info["intervals"], info["interval_details"]["std"])
    return fields


def posterior_not_sampled(summary: dict) -> str:
    """Why the intervals stage samples no posterior for this run, whatever the Laplace check says ("" if it may).

    A run whose model does not explain the data: its intervals are conditional (:func:`interval_status`) whichever
    way they are computed, and a posterior of that model is not worth the sampling's FE runs (400 by default,
    minutes on a 25k-DOF model). So when the run stopped on the evidence of a missing effect (the closure's intervals
    are the extended model's), and when a hybrid run did not converge: issue 40's held-out hd09 (a compliant joint,
    28.5 % left) spent 8.3 minutes on 400 FE runs of an effective sample size of 1.
    """
    evidence = summary.get("evidence") or {}
    if evidence.get("choice") == "closure":
        return ("the run stopped on the evidence of a missing effect; these intervals are conditional on a model "
                "that lacks it")
    if summary.get("own_error"):
        return ("the run converged to the model's own error, above the noise; these intervals are conditional on a "
                "model that explains the data only up to it")
    if _hybrid_not_converged(summary):
        return ("the run did not converge; these intervals are conditional on a model that does not explain the data, "
                "whose posterior is not worth the sampling's FE runs")
    return ""


def _interval_fields(problem, config, store: RunStore, iteration: int, summary: dict) -> dict:
    """95 % intervals at the least-squares optimum near the run's result (tasks.intervals), for summary.json."""
    start = np.array(list(summary["parameters"].values()))
    info = intervals_task(str(store.root), problem, config, iteration, start,
                          not_sampled=posterior_not_sampled(summary))
    if info.get("skipped"):
        return {"intervals_skipped": info["skipped"]}
    fields = summary_interval_fields(info)
    fields["interval_cost"] = {**info["interval_cost"], **_cost_against_update(store, iteration, summary,
                                                                               info["interval_cost"]["seconds"])}
    if config.true_parameters is not None:
        truth = dict(zip(summary["parameters"], config.true_parameters))
        fields["intervals_contain_truth"] = {n: lo is not None and lo <= truth[n] <= hi
                                             for n, (lo, hi) in info["intervals"].items()}
    return fields


def _cost_against_update(store: RunStore, iteration: int, summary: dict, seconds: float) -> dict:
    """The intervals' time in FE runs of this update (the median FE run of the update, a run with its Jacobian
    divided by its cost) and as a share of the update's FE-run equivalents: ``fe_run_seconds``,
    ``fe_run_equivalents``, ``share_of_update_fe_runs``."""
    runs = record.fe_runs(store, iteration)
    per_run = (runs["seconds"] / runs["cost"]).to_numpy(float) if len(runs) else np.empty(0)
    if not per_run.size:
        return {}
    fe_run = float(np.median(per_run))
    if not fe_run > 0:
        return {}
    equivalents = seconds / fe_run
    spent = summary.get("fe_equivalents", summary["fe_evaluations"])
    return {"fe_run_seconds": round(fe_run, 4), "fe_run_equivalents": round(equivalents, 2),
            "share_of_update_fe_runs": round(equivalents / max(1, spent), 4)}


#: ``summary["parameters_source"]`` when the least-squares optimum is reported.
LEAST_SQUARES_SOURCE = "least-squares optimum of the log amplitudes (intervals stage)"


def report_least_squares_optimum(summary: dict, sensors, truth=None) -> dict:
    """Report the least-squares optimum the intervals are centred on instead of the FE run with the lowest
    Eq. (6b) error, which stays in ``summary["lowest_error"]`` (parameters, overall and per-sensor error,
    sample id, parameter errors).

    On noisy data the optimum of the noise-weighted residual is the better estimate: nearer the truth in
    76-85 % of synthetic data sets, with a mean Mahalanobis distance 30-35 % smaller than the minimiser
    of the Eq. (6b) error (``python -m benchmarks.estimators``, measured at efdea20: git show 0cbca1f:docs/estimators.md). Only when the
    Gauss-Newton steps settled at the optimum (else the lowest-error run is kept and
    ``parameters_source`` says so). ``overall_error`` and ``per_sensor_error`` then belong to the
    reported parameters (from the optimum's residual, no FE run); ``converged`` and ``best_sample_id``
    stay the loop's.
    """
    details, errors = summary.get("interval_details"), summary.get("estimate_errors")
    out = {k: v for k, v in summary.items() if k != "estimate_errors"}
    if not details or not errors or not errors.get("at_optimum"):
        out["parameters_source"] = ("lowest Eq. (6b) error among the FE runs (the Gauss-Newton steps of the "
                                    "intervals did not settle at the least-squares optimum)" if details else
                                    "lowest Eq. (6b) error among the FE runs")
        return out
    names = list(summary["parameters"])
    lowest = {"parameters": summary["parameters"], "overall_error": summary["overall_error"],
              "per_sensor_error": summary["per_sensor_error"], "sample_id": summary.get("best_sample_id")}
    if "parameter_errors" in summary:
        lowest["parameter_errors"] = summary["parameter_errors"]
    estimate = {n: float(details["estimate"][n]) for n in names}
    out.update({
        "parameters": estimate,
        "parameters_source": LEAST_SQUARES_SOURCE,
        "overall_error": errors["overall_error"],
        "per_sensor_error": {f"sensor_{int(s)}": float(v) for s, v in zip(sensors, errors["per_sensor_error"])},
        "lowest_error": lowest,
    })
    if truth is not None:
        out["parameter_errors"] = {n: abs(estimate[n] - float(t)) for n, t in zip(names, truth)}
    return out


def repeat_summary(config, runs: list[dict], wall: float, root=None) -> dict:
    """The summary of a run with repeats (``kind`` "repeats"): the repeats' mean parameters and errors, their
    statistics (``repeats``) and each repeat's own summary (``runs``); ``root``: the run's folder."""
    errors = np.array([r["overall_error"] for r in runs])
    params = pd.DataFrame([r["parameters"] for r in runs])
    n_converged = sum(bool(r["converged"]) for r in runs)
    out = {
        "schema_version": SCHEMA_VERSION,
        "kind": "repeats",
        "run_id": config.run_id,
        "parameters": {c: float(v) for c, v in params.mean().items()},
        "overall_error": float(errors.mean()),
        "per_sensor_error": pd.DataFrame([r["per_sensor_error"] for r in runs]).mean().to_dict(),
        "fe_evaluations": int(sum(r["fe_evaluations"] for r in runs)),
        "iterations": int(max(r["iterations"] for r in runs)),
        "converged": n_converged == len(runs),
        "stop_reason": f"{len(runs)} repeats, {n_converged} converged (each repeat's reason: runs[i].stop_reason)",
        "residual": runs[0]["residual"],
        "trainer": config.trainer,
        "strategy": config.strategy,
        "seed": config.seed,
        "wall_seconds": round(wall, 3),
        "run_folder": str(root) if root is not None else str(Path(runs[0]["run_folder"]).parent),
        "repeats": {
            "n": len(runs),
            "seeds": [r["seed"] for r in runs],
            "overall_error": _stats(errors),
            "parameters": {c: _stats(params[c].to_numpy()) for c in params},
            "fe_evaluations": _stats(np.array([r["fe_evaluations"] for r in runs], float)),
            "iterations": _stats(np.array([r["iterations"] for r in runs], float)),
            "success_rate": float(np.mean([r["converged"] for r in runs])),
        },
        "runs": runs,
    }
    if config.true_parameters is not None:
        pe = pd.DataFrame([r["parameter_errors"] for r in runs])
        out["true_parameters"] = runs[0]["true_parameters"]
        out["repeats"]["parameter_errors"] = {c: _stats(pe[c].to_numpy()) for c in pe}
    return out


def _stats(x: np.ndarray) -> dict:
    return {"mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)) if len(x) > 1 else 0.0,
            "min": float(np.min(x)), "max": float(np.max(x))}


def print_summary(summary: dict, file=None) -> None:
    file = file or sys.stdout
    print(file=file)
    print(f"run folder: {summary.get('run_folder', '')}", file=file)
    extra = (f" ({summary['jacobians']} with Jacobian, {summary['fe_equivalents']:g} FE-run equivalents; "
             f"{summary['rounds']} rounds)" if "jacobians" in summary else "")
    state = ("NOT converged" if not summary["converged"] else
             "converged to the model's own error" if summary.get("own_error") else "converged")
    print(f"strategy {summary['strategy']}, trainer {summary['trainer']}: {state} after {summary['iterations']} "
          f"{_round_word(summary['strategy'])}s, "
          f"{summary['fe_evaluations']} FE runs{extra}, {summary['wall_seconds']:.1f} s", file=file)
    if summary.get("own_error"):  # why the run stopped there (strategies.hybrid: status "own error")
        print(f"the model's own error: {summary['own_error']['reason']}", file=file)
    lowest = summary.get("lowest_error")
    if lowest:
        print(f"overall error: {summary['overall_error']:.4%} at the reported parameters, the least-squares optimum "
              f"(the lowest FE run: {lowest['overall_error']:.4%}, sample {lowest['sample_id']})", file=file)
    else:
        print(f"overall error: {summary['overall_error']:.4%}", file=file)
    iv = summary.get("intervals")
    other, label = ((lowest["parameters"], "lowest 6b") if lowest else
                    (summary["interval_details"]["estimate"], "LS optimum") if iv else (None, ""))
    print(f"{'parameter':<10} {'value':>9}" + (f" {'|error|':>9}" if "parameter_errors" in summary else "")
          + (f" {_half_label(summary):>10}" if iv else "") + (f" {label:>10}" if other else ""), file=file)
    for name, value in summary["parameters"].items():
        extra = f" {summary['parameter_errors'][name]:>9.4f}" if "parameter_errors" in summary else ""
        if iv:
            lo, hi = iv[name]["lower95"], iv[name]["upper95"]
            half = None if lo is None or hi is None else (hi - lo) / 2
            extra += f" {'inf':>10}" if half is None else f" {half:>10.4f}" if half >= 1e-3 else f" {half:>10.1e}"
        if other:
            extra += f" {other[name]:>10.4f}"
        print(f"{name:<10} {value:>9.4f}{extra}", file=file)
    if iv:
        for line in interval_sentences(summary):
            print(line, file=file)
    print("per-sensor error: " + ", ".join(f"{k.split('_')[-1]}: {v:.3%}"
                                           for k, v in summary["per_sensor_error"].items()), file=file)


def _round_word(strategy: str) -> str:
    from strategies import registry

    return registry.get(strategy).round_word if strategy in registry.names() else "iteration"


def _half_label(summary: dict) -> str:
    return "+/- (cond.)" if summary.get("interval_status") == INTERVALS_CONDITIONAL else "+/- (95 %)"


def interval_sentences(summary: dict) -> list[str]:
    """How the intervals were made, and a sentence per parameter the data do not pin down or that meets a bound."""
    d = summary["interval_details"]
    cost = summary["interval_cost"]
    kind = cost.get("jacobian_kind", "exact")  # a black-box deck's: forward differences, m + 1 solver runs each
    spent = (f"{cost['jacobians']} {kind} Jacobian" + (" (with its FRF)" if cost["jacobians"] == 1
                                                      else "s (with their FRFs)"))
    if cost.get("fe_runs"):
        spent += f" and {cost['fe_runs']} FE runs"
    against = cost_against_update(summary)
    if against:
        spent += f" ({against})"
    how = ("laplace (Gauss-Newton) at the least-squares optimum of the log amplitudes"
           if summary["interval_method"] == "laplace" else
           f"{summary['interval_method']} of the posterior on the FE model around the least-squares optimum")
    conditional = summary.get("interval_status") == INTERVALS_CONDITIONAL
    title = ("intervals CONDITIONAL (not 95 % intervals)" if conditional else "95 % intervals")
    noise = (f"weighted by the noise per line and channel ({d['noise']})" if "noise" in d else
             f"noise {100 * summary['noise_sigma']:.3g} % ({d['noise_source']}")
    noise += ", " if "noise" not in d else " ("
    lines = [f"{title}: {how}, {noise}{d['distribution']} quantile {d['quantile']:.3f}); cost {spent}"]
    if conditional:
        lines.append(f"warning: the intervals are {summary['conditional_on']}; they hold only if the model were "
                     "right and understate the uncertainty of the parameters")
    if "method_reason" in d:
        lines.append(f"why: {d['method_reason']}")
    if not cost["at_optimum"]:
        lines.append("warning: the Gauss-Newton steps did not settle at the optimum; the intervals are approximate")
    return lines + d["flags"]
