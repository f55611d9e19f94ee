"""FE model updating as a Prefect flow: ``python -m flows.update``.

The default strategy, ``hybrid`` (:mod:`flows.hybrid`), runs Gauss-Newton from
the nominal model and goes global (MRGP emulator, parallel starts) only when
what is left is not noise; each cycle is a subflow ``cycle-<k>``. The paper's
adaptive MRGP loop (``--strategy adaptive``): each iteration is a subflow run
named ``iteration-<k>`` with the tasks
``samples -> fe -> errors -> distribution -> train -> predict -> select``
(see :mod:`tasks.stages`). Everything is written under
``data/runs/<run-id>/``; running again with the same ``--run-id`` resumes
where the last run stopped.

Examples::

    python -m flows.update                                  # benchmark, hybrid strategy
    python -m flows.update --strategy adaptive --no-polish  # the paper's loop, Table 2
    python -m flows.update --trainer pso --seed 3 --run-id pso-3
    python -m flows.update --strategy conventional
    python -m flows.update --repeats 5
    python -m flows.update rerun --run-id pso-3 --iteration 3 --stage train --trainer sao

With no Prefect server configured (no ``PREFECT_API_URL``), Prefect starts a
temporary local API for the run; nothing leaves the machine.
"""

from __future__ import annotations

import os

# Offline and quiet by default; an explicit environment wins.
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_CLOUD_ENABLE_ORCHESTRATION_TELEMETRY", "false")
# The temporary local API must start on a busy 2-core machine too (Prefect's default: 20 s).
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
# One BLAS thread per process: the MRGP's small dense algebra is ~15x slower with
# OpenBLAS's default threading on 2 cores, and FE workers run in parallel anyway.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from prefect import flow  # noqa: E402

from flows import preflight  # noqa: E402
from flows.config import (EMULATES, LINES, LOOPS, OUTPUTS, RESIDUALS, STRATEGIES, TRAINERS, ConfigError,  # noqa: E402
                          UpdateConfig, load_config, parse_windows, stored_settings)
from flows.hybrid import hybrid_summary, run_hybrid  # noqa: E402
from mrgp_core import adaptive  # noqa: E402
from tasks import fe_backends, stages  # noqa: E402
from tasks.hybrid import HYBRID_STAGES, all_runs  # noqa: E402
from tasks.intervals import cost_against_update, intervals_task  # noqa: E402
from tasks.io.measured import MeasuredDataError, read_measured  # noqa: E402
from tasks.model_vtu import model_vtu_task  # noqa: E402
from tasks.polish import POLISH_STAGE, polish_results, polish_task  # noqa: E402
from tasks.runlock import RunLock, RunLockedError  # noqa: E402
from tasks.runstore import RunStore, atomic_write_json, git_commit, package_versions  # noqa: E402
from tasks.update_data import UpdateData, update_data  # noqa: E402

__all__ = ["update_flow", "iteration_flow", "run_update", "main", "rerun_stage"]

#: Config keys that may change between a run and its resume.
# (where FE runs execute does not change their results: fe_backend, dask_address).
# (intervals, noise and posterior_fe change only the intervals stage, computed again when they changed.)
RESUMABLE_CHANGES = {"n_jobs", "run_id", "runs_dir", "repeats", "min_free_mb", "fe_backend", "dask_address",
                     "intervals", "noise", "posterior_fe"}


#: Measurements of the benchmark at the SPEC's actual alpha: their runs report parameter errors.
BENCHMARK_MEASUREMENTS = ("data/benchmark/measured.csv", "data/benchmark/hammer.uff")


# -- the flows ------------------------------------------------------------------------------------
@flow(name="iteration", flow_run_name="iteration-{iteration}", log_prints=True)
def iteration_flow(root: str, config: UpdateConfig, iteration: int, freqs_hz: np.ndarray,
                   measured_amplitude: np.ndarray, m: int, data: UpdateData | None = None) -> dict:
    """One iteration: FE batch and errors, then (unless stopping) the next batch.

    ``data`` (the run's :class:`tasks.update_data.UpdateData`) gives the channels and the
    residual; without it the model's sensors under its default excitation, amplitude residuals.
    """
    stages.samples_task(root, config, iteration, m)
    stages.fe_task(root, config, iteration, freqs_hz, channels=None if data is None else data.channels)
    stages.errors_task(root, config, iteration, measured_amplitude, data=data)
    store = RunStore(root)
    _, _, _, errors = stages.training_data(store, iteration)
    fe_count = _fe_count(store, iteration)
    best = float(errors.min()) if errors.size else float("inf")
    if config.strategy == "conventional":
        decision = adaptive.StopDecision(iteration == 2, best <= config.threshold,
                                         "conventional: one MRGP, best prediction evaluated")
        if iteration == 2:
            return {"stop": True, "converged": decision.converged, "reason": decision.reason, "best": best,
                    "fe": fe_count}
    else:
        decision = adaptive.stopping_rule(best, config.threshold, iteration, config.max_iterations,
                                          fe_count, loop_budget(config), config.s)
        if decision.stop:
            return {"stop": True, "converged": decision.converged, "reason": decision.reason, "best": best,
                    "fe": fe_count}
    stages.distribution_task(root, config, iteration, m)
    stages.train_task(root, config, iteration, data=data)
    stages.predict_task(root, config, iteration, m, data=data)
    stages.select_task(root, config, iteration, m, 1 if config.strategy == "conventional" else config.s)
    print(f"iteration {iteration}: best overall error {best:.4%} after {fe_count} FE runs")
    return {"stop": False, "converged": False, "reason": "continue", "best": best, "fe": fe_count}


@flow(name="mrgp-update", flow_run_name="update-{config.run_id}", log_prints=True)
def update_flow(config: UpdateConfig) -> dict:
    """The whole updating run (all repeats); returns the summary written to ``summary.json``."""
    return run_update(config)


def check_before_run(config: UpdateConfig):
    """Every check that needs no run folder: measured data, model, resume settings, disk.

    Returns the run's :class:`tasks.update_data.UpdateData` (the measured
    channels matched to the model, the selected lines, the residual). Raises
    ConfigError or MeasuredDataError naming the file and key; nothing has
    been written into the run folder then.
    """
    measured = read_measured(config.resolve(config.measured))
    model = load_model_checked(config)
    data = prepare_data(config, measured, model)
    preflight.check_inputs(config, data, model)
    root = config.resolve(config.runs_dir) / config.run_id
    preflight.check_resume(config, root, RESUMABLE_CHANGES)
    required = config.min_free_mb or 2 * preflight.expected_output_mb(
        config, max(data.amplitude.size, data.n_values), model.n_parameters)
    preflight.check_disk(config, root, required)
    if config.fe_backend == "dask":  # an unreachable cluster is refused before any work, not in iteration 1
        try:
            fe_backends.check_dask(config.dask_address)
        except fe_backends.FEBackendError as exc:
            raise ConfigError(str(exc)) from None
    return data


def prepare_data(config: UpdateConfig, measured, model) -> UpdateData:
    """The measured channels matched to the model, with the config's line selection and residual."""
    try:
        return update_data(measured, model, lines=config.lines, line_windows=config.line_windows,
                           resonance_widen=config.resonance_widen, min_coherence=config.min_coherence,
                           residuals=config.residuals)
    except MeasuredDataError:
        raise
    except ValueError as exc:
        raise ConfigError(f"config: key 'residuals': {exc}") from None


def load_model_checked(config: UpdateConfig):
    """The run's FE model; a model file that cannot be used is a ConfigError naming the file and key."""
    from fe_core.io import ModelFileError

    try:
        model = stages.load_model(config.model)
    except ModelFileError as exc:
        raise ConfigError(str(exc)) from None
    return model


def run_update(config: UpdateConfig) -> dict:
    t0 = time.perf_counter()
    measured = check_before_run(config)
    root = config.resolve(config.runs_dir) / config.run_id
    with RunLock(root):
        stale = RunStore(root).remove_temporaries()
        if stale:
            print(f"removed {len(stale)} temporary files left by an interrupted run")
        return _run_locked(config, root, measured, t0)


def _run_locked(config: UpdateConfig, root: Path, measured, t0: float) -> dict:
    if config.repeats == 1:
        summary = _single_run(config, RunStore(root), measured, t0)
    else:
        runs = []
        for i in range(config.repeats):
            sub = config.replace(seed=config.seed + i, repeats=1)
            runs.append(_single_run(sub, RunStore(root / f"repeat={i}"), measured, time.perf_counter()))
        summary = _repeat_summary(config, runs, time.perf_counter() - t0)
        atomic_write_json(root / "summary.json", summary)
    return summary


def _single_run(config: UpdateConfig, store: RunStore, measured: UpdateData, t0: float) -> dict:
    _write_manifest(store, config, measured)
    model = stages.load_model(config.model)
    m = model.n_parameters
    if measured.channels is None and measured.amplitude.shape[1] != model.n_sensors:
        raise MeasuredDataError(f"{measured.source}: {measured.amplitude.shape[1]} sensors, "
                                f"but the model {config.model!r} has {model.n_sensors}")
    for line in measured.describe():
        print(f"measured: {line}")
    write_measured_table(store, measured)
    root = str(store.root)
    if config.strategy == "hybrid":
        iteration, last = run_hybrid(config, store, measured, m)
        summary = hybrid_summary(config, store, iteration, last, measured, time.perf_counter() - t0)
        return _finish_run(config, store, iteration, measured, summary)
    last = None
    iteration = 0
    while True:
        iteration += 1
        last = iteration_flow(root, config, iteration, measured.frequencies_hz, measured.amplitude, m, measured)
        if last["stop"]:
            break
    if uses_polish(config):
        info = polish_task(root, config, iteration, measured.frequencies_hz, measured.amplitude, data=measured)
        print(f"polish: {info['status']} after {info['n']} FE runs, overall error "
              f"{info['error_before']:.4%} -> {info['error_after']:.4%}")
    summary = _summary(config, store, iteration, last, measured, time.perf_counter() - t0)
    return _finish_run(config, store, iteration, measured, summary)


def _finish_run(config: UpdateConfig, store: RunStore, iteration: int, measured, summary: dict) -> dict:
    """Intervals (after a local least-squares stage), model.vtu, then summary.json."""
    if (uses_polish(config) or config.strategy == "hybrid") and config.intervals:
        summary.update(_interval_fields(config, store, iteration, measured, summary))
        if measured.residual == "amplitude":
            summary = report_least_squares_optimum(summary, measured.sensors, config.true_parameters)
        else:  # the optimum of the log amplitudes ignores the phase this run's residual uses
            summary = {k: v for k, v in summary.items() if k != "estimate_errors"}
            summary["parameters_source"] = ("lowest Eq. (6b) error among the FE runs (complex residuals: the "
                                            "intervals' least-squares optimum uses the amplitudes only)")
    model_vtu_task(str(store.root), config.model, summary["parameters"])  # <run>/model.vtu, before the summary
    atomic_write_json(store.root / "summary.json", summary)
    return summary


def _interval_fields(config, store, iteration, measured, summary) -> dict:
    """95 % intervals at the least-squares optimum near the run's result (tasks.intervals), for summary.json."""
    start = np.array(list(summary["parameters"].values()))
    info = intervals_task(str(store.root), config, iteration, measured.frequencies_hz, measured.amplitude, start,
                          data=measured)
    if info.get("skipped"):
        return {"intervals_skipped": info["skipped"]}
    fields = {k: info[k] for k in ("intervals", "covariance", "interval_method", "noise_sigma", "interval_details",
                                   "interval_cost", "estimate_errors") if k in info}
    fields["interval_cost"] = {**info["interval_cost"], **_cost_against_update(config, store, iteration, summary,
                                                                               info["interval_cost"]["seconds"])}
    if config.true_parameters is not None:
        truth = dict(zip(summary["parameters"], config.true_parameters))
        fields["intervals_contain_truth"] = {n: lo is not None and lo <= truth[n] <= hi
                                             for n, (lo, hi) in info["intervals"].items()}
    return fields


#: ``summary["parameters_source"]`` when the least-squares optimum is reported.
LEAST_SQUARES_SOURCE = "least-squares optimum of the log amplitudes (intervals stage)"


def report_least_squares_optimum(summary: dict, sensors, truth=None) -> dict:
    """Report the least-squares optimum the intervals are centred on instead of the FE run with the lowest
    Eq. (6b) error, which stays in ``summary["lowest_error"]`` (parameters, overall and per-sensor error,
    sample id, parameter errors).

    On noisy data the optimum of the noise-weighted residual is the better estimate: nearer the truth in
    76-85 % of synthetic data sets, with a mean Mahalanobis distance 30-35 % smaller than the minimiser
    of the Eq. (6b) error (``python -m benchmarks.estimators``, docs/estimators.md). Only when the
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


def _cost_against_update(config, store: RunStore, iteration: int, summary: dict, seconds: float) -> dict:
    """The intervals' time in FE runs of this update (the median FE run of the update) and as a share of the
    update's FE runs (FE-run equivalents for the hybrid): ``fe_run_seconds``, ``fe_run_equivalents``,
    ``share_of_update_fe_runs``."""
    per_run = _fe_run_seconds(config, store, iteration)
    if not per_run.size:
        return {}
    fe_run = float(np.median(per_run))
    if not fe_run > 0:
        return {}
    equivalents = seconds / fe_run
    spent = summary.get("fe_equivalents", summary["fe_evaluations"])
    return {"fe_run_seconds": round(fe_run, 4), "fe_run_equivalents": round(equivalents, 2),
            "share_of_update_fe_runs": round(equivalents / max(1, spent), 4)}


def _fe_run_seconds(config, store: RunStore, iteration: int) -> np.ndarray:
    """Seconds of one FE run, per FE run of the update (a hybrid run with its Jacobian divided by its cost)."""
    if config.strategy == "hybrid":
        runs, _ = all_runs(store, iteration)
        if "seconds" not in runs:  # a run stored before the column existed
            return np.empty(0)
        return (runs["seconds"] / runs["cost"]).to_numpy()
    per_run = []
    for k in range(1, iteration + 1):
        try:
            fe = store.read_table(k, "fe")
        except Exception:  # an iteration without a readable FE table: measure on the others
            continue
        per_run.append(fe.groupby("sample_id")["seconds"].first().to_numpy())
    return np.concatenate(per_run) if per_run else np.empty(0)


def uses_polish(config: UpdateConfig) -> bool:
    """The polish stage follows the adaptive loop (the conventional baseline stays the paper's)."""
    return bool(config.polish) and config.strategy == "adaptive"


def loop_budget(config: UpdateConfig) -> int:
    """FE runs the MRGP loop may use: the budget minus what is reserved for the polish."""
    return config.max_fe_evaluations - (config.polish_max_fe if uses_polish(config) else 0)


def _fe_count(store: RunStore, iteration: int) -> int:
    """FE runs of iterations 1..``iteration``, plus the polish's once it has finished."""
    n = int(sum(len(store.read_table(k, "samples")) for k in range(1, iteration + 1)))
    if store.is_finished(iteration, POLISH_STAGE):
        n += int(store.stage_info(iteration, POLISH_STAGE)["n"])
    return n


def write_measured_table(store: RunStore, data: UpdateData) -> None:
    """``<run>/measured.parquet``: every measured line and channel as read (receptance, sign-corrected), with
    ``used`` (the value enters the residual), ``selected`` (its line is selected) and the channel's match."""
    from tasks.runstore import _parquet_bytes, atomic_write_bytes

    m = data.measured
    p, n = m.amplitude.shape
    lines = data.selection_lines
    used = np.zeros((p, n), dtype=bool)
    used[lines] = data.mask
    signs = np.array([c["sign"] for c in data.channel_info], float)
    table = pd.DataFrame({
        "frequency_hz": np.repeat(m.frequencies_hz, n), "sensor": np.tile(m.sensors, p).astype(np.int64),
        "channel": np.tile([c["label"] for c in data.channel_info], p),
        "model_sensor": np.tile([c["sensor"] or "" for c in data.channel_info], p),
        "model_excitation": np.tile([c["excitation"] for c in data.channel_info], p),
        "amplitude": m.amplitude.ravel(), "selected": np.repeat(lines, n), "used": used.ravel(),
    })
    if m.complex_frf is not None:
        z = (m.complex_frf * signs).ravel()
        table["real"], table["imag"] = z.real, z.imag
    if m.coherence is not None:
        table["coherence"] = m.coherence.ravel()
    atomic_write_bytes(store.root / "measured.parquet", _parquet_bytes(table))


def _write_manifest(store: RunStore, config: UpdateConfig, data: UpdateData | None = None) -> None:
    old = store.read_manifest()
    cfg = config.to_dict()
    if old is not None:
        before = stored_settings(old["config"])
        changed = {k for k in cfg if before.get(k, cfg[k]) != cfg[k]} - RESUMABLE_CHANGES  # as preflight
        if changed:
            raise ConfigError(
                f"{store.manifest_path}: run {store.root.name!r} was started with other settings "
                f"({', '.join(sorted(changed))}); resume with the same settings or choose a new --run-id"
            )
        old.setdefault("resumes", []).append(_now())
        store.write_manifest(old)
        return
    store.write_manifest({
        "run_id": store.root.name,
        "created": _now(),
        "config": cfg,
        "seed": config.seed,
        "versions": {"python": sys.version.split()[0], **package_versions()},
        "git_commit": git_commit(),
        "stages": list(HYBRID_STAGES if config.strategy == "hybrid" else stages.STAGES),
        "model_checksum": stages.model_fingerprint(config.model),
        **({"measured_data": data.manifest_entry()} if data is not None else {}),
    })


def _now() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")


def _summary(config, store, iterations, last, measured, wall) -> dict:
    ids, X, Y, E = stages.training_data(store, iterations)
    if config.strategy == "conventional":
        final = store.read_table(iterations, "samples")["sample_id"].to_numpy()
        pick = np.flatnonzero(np.isin(ids, final))
        best = int(pick[np.argmin(E[pick])]) if pick.size else int(np.argmin(E))
    else:
        best = int(np.argmin(E))
    polished = polish_results(store, iterations) if uses_polish(config) else None
    if polished is not None and polished[0].size and polished[3].min() < E[best]:
        ids, X, Y, E = (np.concatenate([a, b]) for a, b in zip((ids, X, Y, E), polished))
        best = int(np.argmin(E))
    per_sensor = measured.channel_errors(Y[best])
    names = stages.parameter_names(config)
    summary = {
        "parameters": dict(zip(names, map(float, X[best]))),
        "overall_error": float(E[best]),
        "per_sensor_error": {f"sensor_{int(s)}": float(v) for s, v in zip(measured.sensors, per_sensor)},
        "fe_evaluations": _fe_count(store, iterations),
        "iterations": iterations,
        "converged": bool(E[best] <= config.threshold),
        "stop_reason": last["reason"],
        "trainer": config.trainer,
        "strategy": config.strategy,
        "seed": config.seed,
        "best_sample_id": int(ids[best]),
        "wall_seconds": round(wall, 3),
        "run_folder": str(store.root),
    }
    if polished is not None:
        info = store.stage_info(iterations, POLISH_STAGE)
        summary["polish"] = {k: info[k] for k in ("status", "n", "error_before", "error_after")}
        summary["stop_reason"] = (f"MRGP loop: {last['reason']}; polish: {info['status']} after {info['n']} FE runs "
                                  f"({info['message']})")
    if config.true_parameters is not None:
        truth = np.asarray(config.true_parameters, float)
        summary["parameter_errors"] = dict(zip(names, map(float, np.abs(X[best] - truth))))
    return summary


def _repeat_summary(config, runs: list[dict], wall: float) -> dict:
    errors = np.array([r["overall_error"] for r in runs])
    params = pd.DataFrame([r["parameters"] for r in runs])
    out = {
        "parameters": params.mean().to_dict(),
        "overall_error": float(errors.mean()),
        "per_sensor_error": pd.DataFrame([r["per_sensor_error"] for r in runs]).mean().to_dict(),
        "fe_evaluations": int(sum(r["fe_evaluations"] for r in runs)),
        "iterations": int(max(r["iterations"] for r in runs)),
        "converged": bool(all(r["converged"] for r in runs)),
        "trainer": config.trainer,
        "strategy": config.strategy,
        "wall_seconds": round(wall, 3),
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
        out["repeats"]["parameter_errors"] = {c: _stats(pe[c].to_numpy()) for c in pe}
    return out


def _stats(x: np.ndarray) -> dict:
    return {"mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)) if len(x) > 1 else 0.0,
            "min": float(np.min(x)), "max": float(np.max(x))}


# -- rerun of one stage -------------------------------------------------------------------------
RERUNNABLE = ("train", "predict")


def rerun_stage(run_root: Path, iteration: int, stage: str, trainer: str | None = None) -> Path:
    """Recompute one stage from its stored inputs into a new folder beside the original.

    The output goes to ``iteration=<k>/stage=<stage>.rerun-<trainer>-<UTC time>/``;
    the original stage and everything after it are untouched.
    """
    store = RunStore(run_root)
    manifest = store.read_manifest()
    if manifest is None:
        raise ConfigError(f"{run_root}: no manifest.json; is this a run folder?")
    if stage not in RERUNNABLE:
        raise ConfigError(f"stage {stage!r} cannot be rerun in place; choose one of {', '.join(RERUNNABLE)}")
    config = UpdateConfig(**stored_settings(manifest["config"]))
    tr_loop = stages.trust_region_loop(config)
    needs_data = tr_loop or stages.emulates_modes(config)
    for needed in ("errors", "distribution") if stage == "predict" or tr_loop else ("errors",):
        if not store.is_finished(iteration, needed):
            raise ConfigError(f"{run_root}: iteration {iteration} has no finished '{needed}' stage to rerun from")
    trainer = trainer or config.trainer
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    name = f"{stage}.rerun-{trainer}-{stamp}"
    model = stages.load_model(config.model)
    m = model.n_parameters
    data = prepare_data(config, read_measured(config.resolve(config.measured)), model) if needs_data else None
    if stage == "train":
        stages.train_task.fn(str(store.root), config, iteration, trainer=trainer, output_stage=name, data=data)
    else:
        stages.predict_task.fn(str(store.root), config, iteration, m, output_stage=name, data=data)
    return store.stage_dir(iteration, name)


# -- command line -------------------------------------------------------------------------------
def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m flows.update",
        description="Update the FE model's segment parameters from measured FRF amplitudes "
                    "(adaptive MRGP, Zhou & Tang). Subcommand 'rerun' recomputes one stage of an earlier run.",
        epilog="Settings come from the defaults, then --config, then these flags. See data/update.example.toml.",
    )
    p.add_argument("--config", metavar="PATH", help="TOML file with any of the settings (data/update.example.toml)")
    p.add_argument("--model", metavar="NAME|PATH", help="FE model: three_plate (default, the benchmark) or a "
                                                       "model file model.toml (README: Your own structure)")
    p.add_argument("--measured", metavar="PATH", help="measured FRFs: .csv, .parquet or .uff (README: Measured data) "
                                                      "(default data/benchmark/measured.csv)")
    p.add_argument("--run-id", metavar="ID", help="run folder name under data/runs; an existing id resumes that run")
    p.add_argument("--runs-dir", metavar="PATH", help="where run folders go (default data/runs)")
    p.add_argument("--trainer", choices=TRAINERS, help="MRGP hyper-parameter trainer (default gradient)")
    p.add_argument("--strategy", choices=STRATEGIES,
                   help="hybrid (default: Gauss-Newton from the nominal model, global with the MRGP emulator when "
                        "the residual is not noise), adaptive (the paper's MRGP loop; with --no-polish exactly "
                        "the paper's procedure) or conventional (the paper's 300-sample baseline)")
    p.add_argument("--seed", type=int, help="master random seed (default 0)")
    p.add_argument("--n-jobs", type=int, help="parallel FE processes, -1 = all cores (default 2)")
    p.add_argument("--fe-backend", choices=fe_backends.FE_BACKENDS,
                   help="where FE runs execute: loky processes here (default) or a Dask cluster")
    p.add_argument("--dask-address", metavar="ADDR",
                   help="Dask scheduler for --fe-backend dask, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--repeats", type=int, help="independent runs with seeds seed..seed+N-1 (default 1)")
    p.add_argument("--threshold", type=float, help="stop at this overall error, e.g. 0.01 = 1 %% (default)")
    p.add_argument("--max-iterations", type=int, help="iteration budget (default 12)")
    p.add_argument("--max-fe-evaluations", type=int, help="FE-run budget (default 240)")
    p.add_argument("-q", type=int, help="initial uniform samples (default 20)")
    p.add_argument("-w", type=int, help="candidates predicted per iteration (default 10000)")
    p.add_argument("-s", type=int, help="FE runs per iteration (default 20)")
    p.add_argument("-z", type=int, help="best samples defining the sampling distribution (default 20)")
    p.add_argument("--loop", choices=LOOPS,
                   help="the adaptive strategy's loop: paper (default: Table 2's steps, normal distribution of the "
                        "best z, relative residuals) or trust-region (a change to the paper's loop: a region "
                        "following the best sample, the MRGP emulating the inverse receptance near it, "
                        "Gauss-Newton on its mean)")
    p.add_argument("--emulate", choices=EMULATES,
                   help="what the paper loop's MRGP emulates: modes (default: the lowest modes of each FE run and "
                        "the rest of its receptance; the error of a candidate computed from them) or errors (the "
                        "paper's relative residuals)")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="after the MRGP loop, least squares on the FE model from the best sample (default on)")
    p.add_argument("--polish-max-fe", type=int, metavar="N",
                   help="FE runs reserved for the polish out of --max-fe-evaluations "
                        "(default 200: the loop hands over after 2 iterations)")
    p.add_argument("--polish-target", type=float, metavar="E",
                   help="overall error at which the polish stops (default 1e-4 = 0.01 %%)")
    p.add_argument("--polish-stall-rtol", type=float, metavar="R",
                   help="the polish also stops when its error improved by less than R (relative) over its last "
                        "3 Jacobians, e.g. at the noise of real data (default 0.01; 0 = off)")
    p.add_argument("--outputs", choices=OUTPUTS,
                   help="MRGP over all k responses (full), in a reduced output basis (reduced), or auto "
                        "(default: reduced when k > 200)")
    p.add_argument("--lines", choices=LINES,
                   help="measured lines that enter the update: all (default), those in --line-windows, or windows "
                        "around the measured resonances (half-power band x --resonance-widen)")
    p.add_argument("--line-windows", metavar="LO-HI[,LO-HI...]",
                   help="frequency windows in Hz for --lines windows, e.g. 100-120,280-300")
    p.add_argument("--resonance-widen", type=float, metavar="F",
                   help="factor on each resonance's half-power band for --lines resonances (default 2)")
    p.add_argument("--min-coherence", type=float, metavar="C",
                   help="leave out measured values whose coherence is below C (default 0.9)")
    p.add_argument("--residuals", choices=RESIDUALS,
                   help="amplitude residuals (Eq. 5), complex ones (real and imaginary parts of (Z - H)/|H|), or auto "
                        "(default: complex when the data carry phase, except the legacy sensor form)")
    p.add_argument("--intervals", action=argparse.BooleanOptionalAction, default=None,
                   help="after the polish, 95 %% intervals and the covariance of the parameters (default on; "
                        "their noise level: --noise, else estimated from the residual)")
    p.add_argument("--posterior-fe", type=int, metavar="N",
                   help="FE runs of the sampled posterior used instead of the Laplace intervals where their "
                        "linearisation fails its check (a bound, a curved valley); 0 = never (default 400)")
    from flows.diagnose import add_closure_arguments  # --noise, also the 95 % parameter intervals' noise level

    p.add_argument("--close-loop", action="store_true",
                   help="after the update, trace the residual to a missing effect, add it and update again "
                        "(python -m flows.diagnose on this run; writes <run folder>/closure/)")
    add_closure_arguments(p)
    return p


def _rerun_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m flows.update rerun",
                                description="Recompute one stage of an earlier run from its stored inputs, "
                                            "into a new folder beside the original.")
    p.add_argument("--run-id", required=True, metavar="ID")
    p.add_argument("--runs-dir", default="data/runs", metavar="PATH")
    p.add_argument("--iteration", required=True, type=int)
    p.add_argument("--stage", required=True, choices=RERUNNABLE)
    p.add_argument("--trainer", choices=TRAINERS, help="trainer for a rerun of 'train' (default: the run's)")
    return p


def print_summary(summary: dict, file=sys.stdout) -> None:
    print(file=file)
    print(f"run folder: {summary.get('run_folder', '')}", file=file)
    extra = (f" ({summary['jacobians']} with Jacobian, {summary['fe_equivalents']:g} FE-run equivalents; "
             f"{summary['rounds']} rounds)" if "jacobians" in summary else "")
    print(f"strategy {summary['strategy']}, trainer {summary['trainer']}: "
          f"{'converged' if summary['converged'] else 'NOT converged'} after {summary['iterations']} "
          f"{'cycles' if summary['strategy'] == 'hybrid' else 'iterations'}, "
          f"{summary['fe_evaluations']} FE runs{extra}, {summary['wall_seconds']:.1f} s", file=file)
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
          + (f" {'+/- (95 %)':>10}" if iv else "") + (f" {label:>10}" if other else ""), file=file)
    for name, value in summary["parameters"].items():
        extra = f" {summary['parameter_errors'][name]:>9.4f}" if "parameter_errors" in summary else ""
        if iv:
            lo, hi = iv[name]
            half = None if lo is None else (hi - lo) / 2
            extra += f" {'inf':>10}" if half is None else f" {half:>10.4f}" if half >= 1e-3 else f" {half:>10.1e}"
        if other:
            extra += f" {other[name]:>10.4f}"
        print(f"{name:<10} {value:>9.4f}{extra}", file=file)
    if iv:
        for line in interval_sentences(summary):
            print(line, file=file)
    print("per-sensor error: " + ", ".join(f"{k.split('_')[-1]}: {v:.3%}"
                                           for k, v in summary["per_sensor_error"].items()), file=file)


def interval_sentences(summary: dict) -> list[str]:
    """How the intervals were made, and a sentence per parameter the data do not pin down or that meets a bound."""
    d = summary["interval_details"]
    cost = summary["interval_cost"]
    spent = (f"{cost['jacobians']} exact Jacobian" + (" (with its FRF)" if cost["jacobians"] == 1
                                                       else "s (with their FRFs)"))
    if cost.get("fe_runs"):
        spent += f" and {cost['fe_runs']} FE runs"
    against = cost_against_update(summary)
    if against:
        spent += f" ({against})"
    how = ("laplace (Gauss-Newton) at the least-squares optimum of the log amplitudes"
           if summary["interval_method"] == "laplace" else
           f"{summary['interval_method']} of the posterior on the FE model around the least-squares optimum")
    lines = [f"95 % intervals: {how}, noise {100 * summary['noise_sigma']:.3g} % ({d['noise_source']}, "
             f"{d['distribution']} quantile {d['quantile']:.3f}); cost {spent}"]
    if "method_reason" in d:
        lines.append(f"why: {d['method_reason']}")
    if not cost["at_optimum"]:
        lines.append("warning: the Gauss-Newton steps did not settle at the optimum; the intervals are approximate")
    return lines + d["flags"]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        if argv and argv[0] == "rerun":
            args = _rerun_parser().parse_args(argv[1:])
            root = Path(args.runs_dir)
            root = root if root.is_absolute() else Path(__file__).resolve().parents[1] / root
            out = rerun_stage(root / args.run_id, args.iteration, args.stage, args.trainer)
            print(f"rerun written to {out}")
            return 0
        args = _run_parser().parse_args(argv)
        config = load_config(
            args.config, measured=args.measured, run_id=args.run_id, runs_dir=args.runs_dir, trainer=args.trainer,
            strategy=args.strategy, seed=args.seed, n_jobs=args.n_jobs, fe_backend=args.fe_backend,
            dask_address=args.dask_address, repeats=args.repeats,
            threshold=args.threshold, max_iterations=args.max_iterations,
            max_fe_evaluations=args.max_fe_evaluations, q=args.q, w=args.w, s=args.s, z=args.z,
            polish=args.polish, polish_max_fe=args.polish_max_fe, polish_target=args.polish_target, loop=args.loop,
            emulate=args.emulate,
            polish_stall_rtol=args.polish_stall_rtol, model=args.model, outputs=args.outputs,
            intervals=args.intervals, noise=args.noise, posterior_fe=args.posterior_fe, lines=args.lines,
            line_windows=None if args.line_windows is None else parse_windows(args.line_windows),
            resonance_widen=args.resonance_widen, min_coherence=args.min_coherence, residuals=args.residuals,
        )
        if config.run_id is None:
            stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
            config = config.replace(run_id=f"{config.strategy}-{config.trainer}-seed{config.seed}-{stamp}")
        if config.measured in BENCHMARK_MEASUREMENTS and config.true_parameters is None:
            from fe_core.benchmark import ALPHA_ACTUAL

            config = config.replace(true_parameters=ALPHA_ACTUAL.tolist())
        read_measured(config.resolve(config.measured))  # refuse bad data before any work
    except FileNotFoundError as exc:
        print(f"error: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except (ConfigError, MeasuredDataError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        # Refuse bad inputs, a run in use, or a full / read-only disk before any work.
        check_before_run(config)
        if args.close_loop:
            from flows.diagnose import MASS_FACTORS_REFUSED

            gammas = [n for n in stages.load_model(config.model).parameter_names if n.startswith("gamma_")]
            if gammas:
                raise ConfigError(f"--close-loop: {config.model}: "
                                  f"{MASS_FACTORS_REFUSED.format(names=', '.join(gammas))}")
        lock = RunLock(config.resolve(config.runs_dir) / config.run_id).acquire()
        if lock.stale_owner:
            owner = lock.stale_owner
            print(f"warning: {lock.path}: stale lock of pid {owner.get('pid')} on host {owner.get('host')}, which "
                  "no longer runs; taken over, resuming", file=sys.stderr)
    except (ConfigError, MeasuredDataError, RunLockedError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    try:
        for line in stages.load_model(config.model).placements:  # where the sensor and excitation points landed
            print(f"model: {line}")
        summary = update_flow(config)
    finally:
        lock.release()
    print_summary(summary)
    if args.close_loop:
        from flows.diagnose import DiagnoseError, closure_options, diagnose, print_closure

        try:
            closure = diagnose(config.run_id, config.runs_dir, args.closure_name or "closure",
                               **closure_options(args))
        except (DiagnoseError, MeasuredDataError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print_closure(closure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
