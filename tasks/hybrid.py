"""Prefect tasks of the hybrid strategy (:mod:`mrgp_core.strategies.hybrid`): local, check, global.

Stages (``HYBRID_STAGES``), cycle k being ``iteration=k``::

    iteration=1: local  -> check           (Gauss-Newton from the nominal model; noise or structure?)
    iteration=2: global -> check           (only if the check found structure; and so on)

Every FE run of the ``local`` and ``global`` stages is written as soon as it
finishes to ``iteration=<k>/stage=<name>/sample=<id>.parquet`` (the complex
receptance, with its exact derivative columns ``dreal_<i>``/``dimag_<i>`` when
the strategy asked for it, and the parameters) and logged to
``fe_evaluations.jsonl``. The strategy is deterministic, so a resumed stage
replays the same requests and reads their results back instead of running
them again (the k-th request of a stage is sample ``base + k``). A finished
stage writes ``runs.parquet`` (one row per FE run: round, parameters, overall
error, whether with Jacobian, cost, seconds) and ``responses.parquet`` (the long complex
table); its record holds the minima it ended at and its counts.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import delayed
from prefect import task
from prefect.cache_policies import NO_CACHE

from mrgp_core import adaptive
from mrgp_core.strategies.hybrid import (BudgetSpent, HybridOptions, Layout, Ledger, Residual, check, global_phase,
                                         local_phase)
from tasks import stages
from tasks.faults import kill_point
from tasks.fe_backends import run_unordered
from tasks.runstore import RunStore, _parquet_bytes, atomic_write_bytes

__all__ = ["HYBRID_STAGES", "LOCAL_STAGE", "GLOBAL_STAGE", "CHECK_STAGE", "hybrid_options", "local_task",
           "global_task", "check_task", "evaluate_sample_jacobian", "spent", "all_runs", "JACOBIAN_COST"]

LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE = "local", "global", "check"
HYBRID_STAGES = (LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE)

#: Cost of an FE run with its exact Jacobian, in FE runs: the CPU time ratio of
#: ``fe_core.solvers.sensitivity.frf_jacobian`` (Krylov) to ``model.frf`` on the benchmark, 2.3 measured (one thread,
#: load 10), rounded up; ``python -m benchmarks.suite`` measures it again in every run (docs/suite.md). Data with
#: several references cost this once per reference.
JACOBIAN_COST = 2.5

#: Stored results are reused for requested points this close (max-norm, fraction of the box width).
REPLAY_TOLERANCE = 1e-12


def hybrid_options(config, m: int) -> HybridOptions:
    """The strategy's settings from the run's config (keys documented in flows/config.py)."""
    return HybridOptions(target=config.polish_target, noise=config.noise, max_cost=float(config.max_fe_evaluations),
                         jacobian_cost=JACOBIAN_COST, space_filling=config.s, candidates=config.w,
                         starts=config.starts, trainer=config.trainer, seed=config.seed)


# -- FE runs with Jacobians (in worker processes) -----------------------------------------------
def evaluate_sample_jacobian(model_name: str, sample_id: int, theta: np.ndarray, freqs_hz: np.ndarray,
                             channels: tuple[np.ndarray, np.ndarray] | None = None) -> pd.DataFrame:
    """One FE run with the exact derivative of the receptance (:func:`fe_core.solvers.sensitivity.frf_jacobian`).

    Columns of :func:`tasks.stages.evaluate_sample` plus ``dreal_<i>``, ``dimag_<i>`` (i = 1..m, the
    parameter vector's order): the derivative of ``real``/``imag`` with respect to parameter i, and
    ``cost`` (FE-run equivalents: :data:`JACOBIAN_COST` per reference of the channels). A failed run has
    NaN everywhere.
    """
    from fe_core.solvers.sensitivity import frf_jacobian

    t0 = time.perf_counter()
    model = stages.load_model(model_name)
    theta = np.asarray(theta, float)
    m = theta.size
    p = len(freqs_hz)
    n = model.n_sensors if channels is None else len(channels[0])
    references = 1 if channels is None else np.unique(channels[1]).size
    try:  # one Krylov space for all the channels' references
        Z, dZ = frf_jacobian(model, theta, freqs_hz, channels=channels)
        if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(dZ))):
            raise FloatingPointError("the FRF or its derivative has non-finite values")
        status, message = "ok", ""
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
        Z, dZ = np.full((p, n), np.nan + 1j * np.nan), np.full((p, n, m), np.nan + 1j * np.nan)
        status, message = "failed", f"{type(exc).__name__}: {exc}"
    df = pd.DataFrame({
        "sample_id": np.full(p * n, sample_id, dtype=np.int64),
        "sensor": np.tile(np.arange(1, n + 1), p).astype(np.int64),
        "frequency_hz": np.repeat(np.asarray(freqs_hz, float), n),
        "real": Z.real.ravel(), "imag": Z.imag.ravel(), "status": status, "message": message,
        "seconds": time.perf_counter() - t0, "pid": os.getpid(), "cost": JACOBIAN_COST * references,
    })
    for i in range(m):
        df[f"dreal_{i + 1}"] = dZ[:, :, i].real.ravel()
        df[f"dimag_{i + 1}"] = dZ[:, :, i].imag.ravel()
    return df


def _grid(df: pd.DataFrame, p: int, n: int, m: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(Z (p, n), dZ (p, n, m) or None) of one stored FE result (rows frequency-major, channels fastest)."""
    df = df.sort_values(["frequency_hz", "sensor"], kind="stable")
    Z = (df["real"].to_numpy() + 1j * df["imag"].to_numpy()).reshape(p, n)
    if f"dreal_{m}" not in df.columns:
        return Z, None
    dZ = np.stack([(df[f"dreal_{i + 1}"].to_numpy() + 1j * df[f"dimag_{i + 1}"].to_numpy()).reshape(p, n)
                   for i in range(m)], axis=-1)
    return Z, dZ


def fitted(data) -> tuple[Residual, Layout]:
    """The strategy's residual and layout of the run's data: the kept values (coherence), frequency-major."""
    line, channel = data.cells
    zeta = data.complex_frf[line, channel] if data.residual == "complex" else None
    return Residual(data.amplitude[line, channel], zeta), Layout(np.asarray(data.frequencies_hz, float), line,
                                                                  channel)


class StageEvaluator:
    """``evaluate(points, jacobian)`` for one stage: runs FE in parallel, stores each result, replays on resume."""

    def __init__(self, store: RunStore, config, iteration: int, stage: str, data, m: int, base: int, logger):
        self.store, self.config, self.iteration, self.stage = store, config, iteration, stage
        self.data, self.m, self.next, self.logger = data, m, base, logger
        self.freqs = np.asarray(data.frequencies_hz, float)
        self.p, self.n = data.amplitude.shape
        self.cols = stages.parameter_names(config)
        lower, upper = stages.parameter_box(config, m)
        self.tol = REPLAY_TOLERANCE * float(np.max(upper - lower))
        self.stored = {int(p.stem.split("=")[1]): p for p in sorted(store.stage_dir(iteration, stage).glob(
            "sample=*.parquet"))}
        log = stages.read_fe_log(store.root)
        self.logged = {e["sample_id"] for e in log if e.get("stage") == stage and e["event"] != "discarded"}
        self.ran = 0
        self.rows: list[dict] = []  # one per request: sample_id, round, parameters, jacobian
        self.results: dict[int, pd.DataFrame] = {}
        self.round = 0

    def _set_aside(self, sid: int, path: Path, reason: str) -> None:
        aside = path.with_name(f"{path.name}.corrupt-{int(time.time())}")
        path.rename(aside)
        stages._append_log(self.store, {"iteration": self.iteration, "stage": self.stage, "sample_id": sid,
                                        "event": "discarded", "file": str(path), "reason": reason,
                                        "unix": time.time()})
        self.logger.warning("%s FE result %s: %s; set aside as %s, that point runs again", self.stage, path, reason,
                            aside.name)

    def _replay(self, sid: int, x: np.ndarray, jac: bool) -> pd.DataFrame | None:
        path = self.stored.pop(sid, None)
        if path is None:
            return None
        try:
            df = pd.read_parquet(path)
            xs = df[self.cols].to_numpy()[0].astype(float)
            problem = None
            if np.max(np.abs(xs - x)) > self.tol:
                problem = f"computed for other parameters ({xs.tolist()}) than requested"
            elif jac and f"dreal_{self.m}" not in df.columns:
                problem = "has no Jacobian, which the resumed stage asks for"
            elif len(df) != self.p * self.n:
                problem = f"{len(df)} rows, expected {self.p * self.n}"
        except Exception as exc:  # noqa: BLE001 - any unreadable file is set aside
            problem = f"unreadable ({type(exc).__name__})"
        if problem:
            self._set_aside(sid, path, problem)
            return None
        if sid not in self.logged:  # killed between writing the result and logging it: one FE run
            stages._append_log(self.store, {"iteration": self.iteration, "stage": self.stage, "sample_id": sid,
                                            "event": "recovered", "status": df["status"].iloc[0],
                                            "pid": int(df["pid"].iloc[0]), "unix": time.time()})
        return df

    def __call__(self, points: list, jacobian: list) -> list:
        self.round += 1
        ids, todo = [], []
        for x, jac in zip(points, jacobian):
            sid = self.next
            self.next += 1
            ids.append(sid)
            self.rows.append({"sample_id": sid, "round": self.round, "jacobian": bool(jac),
                              **dict(zip(self.cols, map(float, x)))})
            df = self._replay(sid, np.asarray(x, float), jac)
            if df is not None:
                self.results[sid] = df
            else:
                todo.append((sid, np.asarray(x, float), jac))
        if todo:
            fn = {True: evaluate_sample_jacobian, False: stages.evaluate_sample}
            jobs = {sid: delayed(fn[jac])(self.config.model, sid, x, self.freqs, self.data.channels)
                    for sid, x, jac in todo}
            alpha = {sid: x for sid, x, _ in todo}
            done = run_unordered(jobs, lambda r: int(r["sample_id"].iloc[0]), fe_backend=self.config.fe_backend,
                                 n_jobs=self.config.n_jobs, dask_address=self.config.dask_address,
                                 label=f"iteration {self.iteration}, stage {self.stage}", logger=self.logger)
            for result in done:
                sid = int(result["sample_id"].iloc[0])
                for j, c in enumerate(self.cols):
                    result[c] = alpha[sid][j]
                atomic_write_bytes(self.store.stage_dir(self.iteration, self.stage) / f"sample={sid:06d}.parquet",
                                   _parquet_bytes(result))
                kill_point(f"{self.stage}-result-written/iteration={self.iteration}/sample={sid}")
                stages._append_log(self.store, {"iteration": self.iteration, "stage": self.stage, "sample_id": sid,
                                                "event": "evaluated", "status": result["status"].iloc[0],
                                                "pid": int(result["pid"].iloc[0]), "unix": time.time()})
                self.results[sid] = result
                self.ran += 1
        self.logger.info("iteration %d, stage %s: round %d, %d FE runs (%d with Jacobian)", self.iteration,
                         self.stage, self.round, len(points), sum(map(bool, jacobian)))
        line, channel = self.data.cells
        out = []
        for sid, jac in zip(ids, jacobian):
            df = self.results[sid]
            Z, dZ = _grid(df, self.p, self.n, self.m)
            cost = float(df["cost"].iloc[0]) if jac and "cost" in df.columns else (JACOBIAN_COST if jac else 1.0)
            out.append((Z[line, channel], dZ[line, channel] if jac else None, cost))
        return out

    def write(self, info: dict) -> dict:
        """Write ``runs`` and ``responses`` and finish the stage with ``info``."""
        for sid, path in self.stored.items():  # results the resumed stage never asked for (not expected)
            self._set_aside(sid, path, "not requested by the resumed stage")
        runs = pd.DataFrame(self.rows, columns=["sample_id", "round", "jacobian", *self.cols])
        errors, status, costs, seconds = [], [], [], []
        for sid, jac in zip(runs["sample_id"], runs["jacobian"]):
            df = self.results[int(sid)]
            seconds.append(float(df["seconds"].iloc[0]))
            Z, _ = _grid(df, self.p, self.n, self.m)
            ok = bool(np.all(np.isfinite(Z)))
            errors.append(float(adaptive.overall_error(self.data.residuals(Z))) if ok else np.nan)
            status.append("ok" if ok else "failed")
            costs.append(float(df["cost"].iloc[0]) if jac and "cost" in df.columns else (JACOBIAN_COST if jac
                                                                                          else 1.0))
        runs["overall_error"] = errors
        runs["status"] = status
        runs["cost"] = costs
        runs["seconds"] = seconds  # the FE run's own time (the worker's), for the cost of later stages
        runs = runs.astype({"sample_id": np.int64, "round": np.int64, "jacobian": bool})
        keep = ["sample_id", "sensor", "frequency_hz", "real", "imag", "status"]
        parts = [self.results[int(sid)][keep] for sid in runs["sample_id"]]
        responses = (pd.concat(parts, ignore_index=True) if parts else
                     pd.DataFrame({c: pd.Series(dtype=t) for c, t in zip(keep, (np.int64, np.int64, float, float,
                                                                                 float, object))}))
        self.store.write_table(self.iteration, self.stage, "runs", runs)
        self.store.write_table(self.iteration, self.stage, "responses", responses)
        self.store.finish(self.iteration, self.stage, ["runs", "responses"], info)
        return self.store.stage_info(self.iteration, self.stage)


# -- what earlier stages did -----------------------------------------------------------------------
def _stage_list(store: RunStore, upto: int) -> list[tuple[int, str]]:
    out = []
    for k in range(1, upto + 1):
        for stage in (LOCAL_STAGE, GLOBAL_STAGE):
            if store.is_finished(k, stage):
                out.append((k, stage))
    return out


def spent(store: RunStore, upto: int) -> dict:
    """FE runs, Jacobians, rounds and FE-run equivalents (``cost``) of the finished FE stages of cycles 1..``upto``."""
    total = {"evaluations": 0, "jacobians": 0, "rounds": 0, "cost": 0.0}
    for k, stage in _stage_list(store, upto):
        info = store.stage_info(k, stage)
        for key in total:
            total[key] += info[key]
    return total


def all_runs(store: RunStore, upto: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(runs, responses) of every finished FE stage of cycles 1..``upto``, in sample order."""
    runs, responses = [], []
    for k, stage in _stage_list(store, upto):
        r = store.read_table(k, stage, "runs")
        r.insert(0, "stage", stage)
        r.insert(0, "iteration", np.int64(k))
        runs.append(r)
        responses.append(store.read_table(k, stage, "responses"))
    if not runs:
        return pd.DataFrame(), pd.DataFrame()
    return (pd.concat(runs, ignore_index=True).sort_values("sample_id", kind="stable"),
            pd.concat(responses, ignore_index=True))


def _ledger(config, evaluate, data, m: int, runs: pd.DataFrame, responses: pd.DataFrame, used: dict) -> Ledger:
    """A ledger holding earlier cycles' FE runs (``all_runs``; for the emulator) and the budget they left
    (``used``: :func:`spent`)."""
    options = hybrid_options(config, m)
    residual, _ = fitted(data)
    ledger = Ledger(evaluate, residual, options.max_cost - used["cost"], options.jacobian_cost)
    if len(runs):
        line, channel = data.cells
        p, n = data.amplitude.shape
        ok = runs[runs["status"] == "ok"]
        by_sample = dict(tuple(responses.groupby("sample_id", sort=False)))
        for sid, x in zip(ok["sample_id"], ok[stages.parameter_names(config)].to_numpy()):
            Z, _ = _grid(by_sample[sid], p, n, m)
            ledger.responses.append((x, Z[line, channel]))
    return ledger


def _minimum_info(minimum) -> dict:
    return {"x": [float(v) for v in minimum.x], "error": float(minimum.error), "status": minimum.status}


def _phase_info(ledger: Ledger, evaluator: StageEvaluator, minima: list, status: str, seconds: float) -> dict:
    return {"evaluations": ledger.evaluations, "jacobians": ledger.jacobians, "rounds": ledger.rounds,
            "cost": ledger.cost,
            "ran_now": evaluator.ran, "status": status, "minima": [_minimum_info(mn) for mn in minima],
            "best_error": min([h[2] for h in ledger.history] or [float("inf")]), "seconds": seconds}


# -- the tasks ---------------------------------------------------------------------------------------
@task(name="local", task_run_name="iteration-{iteration}-local", cache_policy=NO_CACHE)
def local_task(root: str, config, iteration: int, data, start) -> dict:
    """Gauss-Newton with exact Jacobians from ``start`` (the nominal model), one FE run per round."""
    def phase(ledger, lower, upper, options):
        minimum = local_phase(ledger, np.asarray(start, float), lower, upper, options)
        return [minimum], minimum.status

    return _fe_stage(root, config, iteration, LOCAL_STAGE, data, len(start), phase)


@task(name="global", task_run_name="iteration-{iteration}-global", cache_policy=NO_CACHE)
def global_task(root: str, config, iteration: int, data, minima) -> dict:
    """One global cycle: space-filling round, emulator, parallel Gauss-Newton runs away from ``minima``."""
    def phase(ledger, lower, upper, options):
        found = global_phase(ledger, lower, upper, [np.asarray(x, float) for x in minima], options, iteration - 1)
        return found, (found[0].status if found else "budget")

    return _fe_stage(root, config, iteration, GLOBAL_STAGE, data, len(minima[0]), phase)


def _fe_stage(root: str, config, iteration: int, stage: str, data, m: int, phase) -> dict:
    """Run one FE stage: ``phase(ledger, lower, upper, options) -> (minima, status)`` on a ledger holding the
    earlier cycles' FE runs; every FE run stored and replayed (:class:`StageEvaluator`)."""
    store = RunStore(root)
    logger = stages._logger()
    if stages._done(store, iteration, stage):
        return store.stage_info(iteration, stage)
    options = hybrid_options(config, m)
    lower, upper = stages.solver_box(config, m)
    runs, responses = all_runs(store, iteration - 1)  # read once: the next sample id and the emulator's data
    base = int(runs["sample_id"].max()) + 1 if len(runs) else 0
    evaluator = StageEvaluator(store, config, iteration, stage, data, m, base, logger)
    ledger = _ledger(config, evaluator, data, m, runs, responses, spent(store, iteration - 1))
    t0 = time.perf_counter()
    try:
        minima, status = phase(ledger, lower, upper, options)
    except BudgetSpent:
        minima, status = [], "budget"
    info = _phase_info(ledger, evaluator, minima, status, time.perf_counter() - t0)
    logger.info("iteration %d, stage %s: %s after %d FE runs (%d with Jacobian) in %d rounds, best overall "
                "error %.4g %%", iteration, stage, status, ledger.evaluations, ledger.jacobians, ledger.rounds,
                100 * info["best_error"])
    return evaluator.write(info)


@task(name="check", task_run_name="iteration-{iteration}-check", cache_policy=NO_CACHE)
def check_task(root: str, config, iteration: int, data) -> dict:
    """Noise or structure at the best minimum of this cycle's stage (:func:`mrgp_core.strategies.hybrid.check`)."""
    store = RunStore(root)
    if stages._done(store, iteration, CHECK_STAGE):
        return store.stage_info(iteration, CHECK_STAGE)
    stage = LOCAL_STAGE if store.is_finished(iteration, LOCAL_STAGE) else GLOBAL_STAGE
    info = store.stage_info(iteration, stage)
    out = {"stage": stage, "at_floor": False, "reason": f"{stage} stage ended without a minimum ({info['status']})",
           "status": info["status"], "minimum": None}
    if info["minima"]:
        best = info["minima"][0]
        m = len(best["x"])
        runs = store.read_table(iteration, stage, "runs")
        responses = store.read_table(iteration, stage, "responses")
        ok = runs[runs["status"] == "ok"]
        X = ok[stages.parameter_names(config)].to_numpy()
        sid = int(ok["sample_id"].to_numpy()[int(np.argmin(np.max(np.abs(X - np.array(best["x"])), axis=1)))])
        p, n = data.amplitude.shape
        Z, _ = _grid(responses[responses["sample_id"] == sid], p, n, m)
        residual, layout = fitted(data)
        line, channel = data.cells
        verdict = check(Z[line, channel], residual, layout, m, hybrid_options(config, m))
        out.update({"at_floor": bool(verdict.at_floor or best["status"] == "target"), "reason": verdict.reason,
                    "rms": verdict.rms, "sigma": verdict.sigma if np.isfinite(verdict.sigma) else None,
                    "sigma_source": verdict.sigma_source, "p_chi2": verdict.p_chi2, "minimum": best})
    table = pd.DataFrame({"at_floor": [out["at_floor"]], "reason": [out["reason"]]})
    store.write_table(iteration, CHECK_STAGE, CHECK_STAGE, table)
    store.finish(iteration, CHECK_STAGE, [CHECK_STAGE], out)
    stages._logger().info("iteration %d, stage check: %s (%s)", iteration,
                          "at the floor" if out["at_floor"] else "structure left: global search", out["reason"])
    return store.stage_info(iteration, CHECK_STAGE)
