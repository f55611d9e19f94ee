"""The polish stage: local least squares on the FE model after the MRGP loop.

Runs :func:`mrgp_core.polish.polish` from the best FE-evaluated sample of the
loop, inside the search box, with the FE runs of each finite-difference
Jacobian in parallel on the FE stage's backend (loky or Dask, with the same
re-submission of runs lost with a worker: :mod:`tasks.fe_backends`). Every FE run is written as soon as it finishes
to ``iteration=<K>/stage=polish/sample=<id>.parquet`` (with its parameters)
and logged to ``fe_evaluations.jsonl``; the polish is deterministic, so a
resumed polish replays the same points and reads their results back instead
of running them again. When it ends, ``polish.parquet`` (one row per FE run:
parameters, overall and per-sensor errors) and ``residuals.parquet`` are
written and the stage is recorded as finished.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import delayed
from prefect import task
from prefect.cache_policies import NO_CACHE

from mrgp_core import adaptive
from mrgp_core.polish import polish
from tasks import stages
from tasks.faults import kill_point
from tasks.fe_backends import run_unordered
from tasks.runstore import RunStore, _parquet_bytes, atomic_write_bytes

__all__ = ["POLISH_STAGE", "polish_task", "polish_results"]

POLISH_STAGE = "polish"

#: Stored polish FE runs are reused for requested points this close (max-norm, as a
#: fraction of the box width): far below any finite-difference step (1e-6).
REPLAY_TOLERANCE = 1e-12

def _set_aside(store: RunStore, iteration: int, sid: int, path: Path, reason: str) -> None:
    """Rename a polish FE result that cannot be used and log it as discarded; its point runs again."""
    aside = path.with_name(f"{path.name}.corrupt-{int(time.time())}")
    path.rename(aside)
    stages._append_log(store, {"iteration": iteration, "stage": POLISH_STAGE, "sample_id": sid,
                               "event": "discarded", "file": str(path), "reason": reason, "unix": time.time()})
    stages._logger().warning("polish FE result %s: %s; set aside as %s, that point runs again",
                             path, reason, aside.name)


def _sample_files(store: RunStore, iteration: int, cols: list[str], rows: int) -> dict[int, Path]:
    """Valid per-sample FE results of an earlier polish; a damaged one is set aside and run again."""
    out = {}
    for path in sorted(store.stage_dir(iteration, POLISH_STAGE).glob("sample=*.parquet")):
        sid = int(path.stem.split("=")[1])
        try:
            table = pd.read_parquet(path)
            problem = None
            missing = [c for c in (*stages.FE_RESULT_COLUMNS, *cols) if c not in table.columns]
            if missing:
                problem = f"columns {missing} missing"
            elif len(table) != rows or not (table["sample_id"] == sid).all():
                problem = f"{len(table)} rows or wrong sample ids"
        except Exception as exc:  # noqa: BLE001 - any unreadable file is set aside
            problem = f"unreadable ({type(exc).__name__})"
        if problem:
            _set_aside(store, iteration, sid, path, problem)
            continue
        out[sid] = path
    return out


@task(name="polish", task_run_name="iteration-{iteration}-polish", cache_policy=NO_CACHE)
def polish_task(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray,
                data=None) -> dict:
    """Least squares on the FE model from the best sample of iterations 1..``iteration``.

    With ``data`` (:class:`tasks.update_data.UpdateData`) the FE runs give its channels and the
    residual vector is its residual (amplitude or complex, the kept values), as in the loop.
    """
    store = RunStore(root)
    logger = stages._logger()
    if stages._done(store, iteration, POLISH_STAGE):
        return store.stage_info(iteration, POLISH_STAGE)
    ids, X, Y, E = stages.training_data(store, iteration)
    m = X.shape[1]
    cols = stages.parameter_names(config)
    p, n = measured_amplitude.shape
    best = int(np.argmin(E))
    lower, upper = stages.solver_box(config, m)

    # The polish asks for its new points in a deterministic sequence; the k-th new point
    # is sample base + k. On resume, a stored result with that id is reused if it was
    # computed for (nearly) the same parameters: a resumed least-squares step can differ
    # from the stored one in the last bits (BLAS results depend on memory alignment).
    # Anything else stored under that id is set aside and the point runs again.
    base = stages._next_sample_id(store, iteration)
    stored = _sample_files(store, iteration, cols, measured_amplitude.size)
    log = stages.read_fe_log(store.root)
    logged = {e["sample_id"] for e in log if e.get("stage") == POLISH_STAGE and e["event"] != "discarded"}
    tol = REPLAY_TOLERANCE * float(np.max(upper - lower))
    if config.polish_max_fe < m + 1:
        logger.warning("polish_max_fe = %d is less than one Jacobian and a step (%d FE runs): the polish can "
                       "do nothing", config.polish_max_fe, m + 1)
    results: dict[int, tuple] = {}  # sample id -> (parameters, residuals, FRF)
    state = {"ran": 0, "next": base}

    def evaluate(points: list[np.ndarray]) -> list[np.ndarray]:
        ids, todo = [], []
        for x in points:
            sid = state["next"]
            state["next"] += 1
            ids.append(sid)
            path = stored.pop(sid, None)
            if path is not None:
                df = pd.read_parquet(path)
                xs = df[cols].to_numpy()[0].astype(float)
                if np.max(np.abs(xs - x)) <= tol:
                    results[sid] = (xs, *_residuals(df, measured_amplitude, data))
                    if sid not in logged:  # killed between writing the result and logging it: one FE run
                        stages._append_log(store, {"iteration": iteration, "stage": POLISH_STAGE,
                                                   "sample_id": sid, "event": "recovered",
                                                   "status": df["status"].iloc[0], "pid": int(df["pid"].iloc[0]),
                                                   "unix": time.time()})
                    continue
                _set_aside(store, iteration, sid, path, f"computed for other parameters ({xs.tolist()}) than requested")
            todo.append((sid, x))
        if todo:
            channels = None if data is None else data.channels
            jobs = {sid: delayed(stages.evaluate_sample)(config.model, sid, x, freqs_hz, channels) for sid, x in todo}
            alpha = dict(todo)
            runs = run_unordered(jobs, lambda r: int(r["sample_id"].iloc[0]), fe_backend=config.fe_backend,
                                 n_jobs=config.n_jobs, dask_address=config.dask_address,
                                 label=f"iteration {iteration}, stage polish", logger=logger)
            for result in runs:
                sid = int(result["sample_id"].iloc[0])
                for j, c in enumerate(cols):
                    result[c] = alpha[sid][j]
                atomic_write_bytes(store.stage_dir(iteration, POLISH_STAGE) / f"sample={sid:06d}.parquet",
                                   _parquet_bytes(result))
                kill_point(f"polish-result-written/iteration={iteration}/sample={sid}")
                stages._append_log(store, {"iteration": iteration, "stage": POLISH_STAGE, "sample_id": sid,
                                           "event": "evaluated", "status": result["status"].iloc[0],
                                           "pid": int(result["pid"].iloc[0]), "unix": time.time()})
                results[sid] = (alpha[sid], *_residuals(result, measured_amplitude, data))
                state["ran"] += 1
        errors = [float(np.mean(np.abs(r))) for _, r, _ in results.values() if np.all(np.isfinite(r))]
        logger.info("iteration %d, stage polish: %d FE runs, best overall error so far %.4g %%", iteration,
                    len(results), 100 * min([E[best], *errors]))
        return [results[sid][1] for sid in ids]

    t0 = time.perf_counter()
    result = polish(evaluate, X[best], lower, upper, residuals0=Y[best], target=config.polish_target,
                    max_evaluations=config.polish_max_fe, stall_window=None if config.polish_stall_rtol > 0 else 0,
                    stall_rtol=config.polish_stall_rtol)
    seconds = time.perf_counter() - t0

    # One row per FE run of the polish, in request order.
    rows, res_parts = [], []
    for sid in sorted(results):
        x, r, Z = results[sid]
        ok = bool(np.all(np.isfinite(r)))
        row = {"sample_id": sid, "step": sid - base, **dict(zip(cols, x)),
               "overall_error": float(adaptive.overall_error(r)) if ok else np.nan,
               "status": "ok" if ok else "failed"}
        per_channel = adaptive.per_sensor_error(r, n) if data is None else data.channel_errors(r)
        for j, e in enumerate(per_channel if ok else np.full(n, np.nan)):
            row[f"error_sensor_{j + 1}"] = float(e)
        rows.append(row)
        if data is None:
            res_parts.append(pd.DataFrame({"sample_id": np.int64(sid), "frequency_hz": np.repeat(freqs_hz, n),
                                           "sensor": np.tile(np.arange(1, n + 1), p).astype(np.int64),
                                           "residual": r}))
        else:
            columns = data.residual_columns(Z)
            res_parts.append(pd.DataFrame({"sample_id": np.full(columns["residual"].size, sid, np.int64),
                                           **columns}))
    for sid, path in stored.items():  # results of points this polish never asked for (not expected)
        _set_aside(store, iteration, sid, path, "not requested by the resumed polish")
    table = pd.DataFrame(rows, columns=["sample_id", "step", *cols, "overall_error", "status",
                                        *(f"error_sensor_{j + 1}" for j in range(n))])
    table = table.astype({"sample_id": np.int64, "step": np.int64})
    residuals = (pd.concat(res_parts, ignore_index=True) if res_parts else
                 pd.DataFrame({"sample_id": pd.Series(dtype=np.int64), "frequency_hz": pd.Series(dtype=float),
                               "sensor": pd.Series(dtype=np.int64), "residual": pd.Series(dtype=float)}))
    store.write_table(iteration, POLISH_STAGE, POLISH_STAGE, table)
    store.write_table(iteration, POLISH_STAGE, "residuals", residuals)
    best_id = int(ids[best])
    if len(table) and table["overall_error"].min() < E[best]:
        best_id = int(table.loc[table["overall_error"].idxmin(), "sample_id"])
    info = {"n": int(len(table)), "ran_now": state["ran"], "status": result.status, "message": result.message,
            "start_sample_id": int(ids[best]), "error_before": float(E[best]), "error_after": float(result.error),
            "best_sample_id": best_id, "seconds": seconds}
    store.finish(iteration, POLISH_STAGE, [POLISH_STAGE, "residuals"], info)
    logger.info("iteration %d, stage polish: %s after %d FE runs, overall error %.4g %% -> %.4g %%", iteration,
                result.status, len(table), 100 * E[best], 100 * result.error)
    return store.stage_info(iteration, POLISH_STAGE)


def _residuals(fe: pd.DataFrame, measured_amplitude: np.ndarray, data=None) -> tuple[np.ndarray, np.ndarray]:
    """(residual vector, FRF (p, n)) of one per-sample FE table; NaN for a failed run.

    The vector is Eq. (5)'s relative amplitude residuals, or ``data``'s residual when given.
    """
    fe = fe.sort_values(["frequency_hz", "sensor"], kind="stable")
    Z = (fe["real"].to_numpy() + 1j * fe["imag"].to_numpy()).reshape(measured_amplitude.shape)
    if data is not None:
        return data.residuals(Z), Z
    return adaptive.relative_residuals(np.hypot(Z.real, Z.imag)[None], measured_amplitude)[0], Z


def polish_results(store: RunStore, iteration: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(sample_ids, X, residuals, errors) of a finished polish's successful FE runs, or None."""
    if not store.is_finished(iteration, POLISH_STAGE):
        return None
    table = store.read_table(iteration, POLISH_STAGE)
    table = table[table["status"] == "ok"]
    res = store.read_table(iteration, POLISH_STAGE, "residuals")
    cols = stages.parameter_columns(table)
    ids = table["sample_id"].to_numpy()
    return ids, table[cols].to_numpy(), stages.residual_matrix(res, ids), table["overall_error"].to_numpy()
