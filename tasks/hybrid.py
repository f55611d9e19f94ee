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
error, whether with Jacobian) and ``responses.parquet`` (the long complex
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

from mrgp_core.strategies.hybrid import BudgetSpent, HybridOptions, Ledger, check, global_phase, local_phase
from tasks import stages
from tasks.faults import kill_point
from tasks.fe_backends import run_unordered
from tasks.polish import polish_lower_bound
from tasks.runstore import RunStore, _parquet_bytes, atomic_write_bytes

__all__ = ["HYBRID_STAGES", "LOCAL_STAGE", "GLOBAL_STAGE", "CHECK_STAGE", "hybrid_options", "local_task",
           "global_task", "check_task", "evaluate_sample_jacobian", "spent", "all_runs", "JACOBIAN_COST"]

LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE = "local", "global", "check"
HYBRID_STAGES = (LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE)

#: Cost of an FE run with its exact Jacobian, in FE runs (CPU time ratio measured on the benchmark,
#: ``python -m benchmarks.suite`` prints the ratio of each run; docs/suite.md).
JACOBIAN_COST = 2.5

#: Stored results are reused for requested points this close (max-norm, fraction of the box width).
REPLAY_TOLERANCE = 1e-12


def hybrid_options(config, m: int) -> HybridOptions:
    """The strategy's settings from the run's config (keys documented in flows/config.py)."""
    return HybridOptions(target=config.polish_target, noise=config.noise, max_cost=float(config.max_fe_evaluations),
                         jacobian_cost=JACOBIAN_COST, space_filling=config.s, candidates=config.w,
                         starts=config.starts, trainer=config.trainer, seed=config.seed)


def _box(config, m: int) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = stages.parameter_box(config, m)
    return np.maximum(lower, polish_lower_bound(-1.0)), upper


# -- FE runs with Jacobians (in worker processes) -----------------------------------------------
def evaluate_sample_jacobian(model_name: str, sample_id: int, alpha: np.ndarray, freqs_hz: np.ndarray) -> pd.DataFrame:
    """One FE run with the exact derivative of the receptance (:func:`fe_core.sensitivity.frf_jacobian`).

    Columns of :func:`tasks.stages.evaluate_sample` plus ``dreal_<i>``, ``dimag_<i>`` (i = 1..m): the
    derivative of ``real``/``imag`` with respect to ``alpha_i``. A failed run has NaN everywhere.
    """
    from fe_core.sensitivity import frf_jacobian

    t0 = time.perf_counter()
    model = stages.load_model(model_name)
    alpha = np.asarray(alpha, float)
    m = alpha.size
    p, n = len(freqs_hz), model.n_sensors
    try:
        Z, dZ = frf_jacobian(model, alpha, freqs_hz)
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
        "seconds": time.perf_counter() - t0, "pid": os.getpid(),
    })
    for i in range(m):
        df[f"dreal_{i + 1}"] = dZ[:, :, i].real.ravel()
        df[f"dimag_{i + 1}"] = dZ[:, :, i].imag.ravel()
    return df


def _complex(df: pd.DataFrame, m: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(Z (p*n,), dZ (p*n, m) or None) of one stored FE result, frequency-major (Eq. 5 layout)."""
    df = df.sort_values(["frequency_hz", "sensor"], kind="stable")
    Z = df["real"].to_numpy() + 1j * df["imag"].to_numpy()
    if f"dreal_{m}" not in df.columns:
        return Z, None
    dZ = np.column_stack([df[f"dreal_{i + 1}"].to_numpy() + 1j * df[f"dimag_{i + 1}"].to_numpy()
                          for i in range(m)])
    return Z, dZ


class StageEvaluator:
    """``evaluate(points, jacobian)`` for one stage: runs FE in parallel, stores each result, replays on resume."""

    def __init__(self, store: RunStore, config, iteration: int, stage: str, freqs_hz: np.ndarray, m: int,
                 base: int, logger):
        self.store, self.config, self.iteration, self.stage = store, config, iteration, stage
        self.freqs, self.m, self.next, self.logger = freqs_hz, m, base, logger
        self.cols = stages.param_columns(m)
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
            elif len(df) != len(self.freqs) * stages.load_model(self.config.model).n_sensors:
                problem = f"{len(df)} rows"
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
            jobs = {sid: delayed(fn[jac])(self.config.model, sid, x, self.freqs) for sid, x, jac in todo}
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
        out = []
        for sid, jac in zip(ids, jacobian):
            Z, dZ = _complex(self.results[sid], self.m)
            out.append((Z, dZ if jac else None))
        return out

    def write(self, u: np.ndarray, info: dict) -> dict:
        """Write ``runs`` and ``responses`` and finish the stage with ``info``."""
        for sid, path in self.stored.items():  # results the resumed stage never asked for (not expected)
            self._set_aside(sid, path, "not requested by the resumed stage")
        runs = pd.DataFrame(self.rows, columns=["sample_id", "round", "jacobian", *self.cols])
        errors, status = [], []
        for sid in runs["sample_id"]:
            Z, _ = _complex(self.results[int(sid)], self.m)
            ok = bool(np.all(np.isfinite(Z)))
            errors.append(float(np.mean(np.abs(np.abs(Z) / u - 1.0))) if ok else np.nan)
            status.append("ok" if ok else "failed")
        runs["overall_error"] = errors
        runs["status"] = status
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
    """FE runs, Jacobians, rounds and FE-run equivalents of the finished FE stages of cycles 1..``upto``."""
    total = {"evaluations": 0, "jacobians": 0, "rounds": 0}
    for k, stage in _stage_list(store, upto):
        info = store.stage_info(k, stage)
        for key in total:
            total[key] += int(info[key])
    total["cost"] = total["evaluations"] + (JACOBIAN_COST - 1.0) * total["jacobians"]
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


def _ledger(store: RunStore, config, upto: int, evaluate, u: np.ndarray, m: int) -> Ledger:
    """A ledger holding the FE runs of cycles 1..``upto`` (for the emulator) and the budget they left."""
    options = hybrid_options(config, m)
    used = spent(store, upto)
    ledger = Ledger(evaluate, u, options.max_cost - used["cost"], options.jacobian_cost)
    runs, responses = all_runs(store, upto)
    if len(runs):
        ok = runs[runs["status"] == "ok"]
        for sid, x in zip(ok["sample_id"], ok[stages.param_columns(m)].to_numpy()):
            part = responses[responses["sample_id"] == sid].sort_values(["frequency_hz", "sensor"], kind="stable")
            ledger.responses.append((x, part["real"].to_numpy() + 1j * part["imag"].to_numpy()))
    return ledger


def _minimum_info(minimum) -> dict:
    return {"x": [float(v) for v in minimum.x], "error": float(minimum.error), "status": minimum.status}


def _phase_info(ledger: Ledger, evaluator: StageEvaluator, minima: list, status: str, seconds: float) -> dict:
    return {"evaluations": ledger.evaluations, "jacobians": ledger.jacobians, "rounds": ledger.rounds,
            "ran_now": evaluator.ran, "status": status, "minima": [_minimum_info(mn) for mn in minima],
            "best_error": min([h[2] for h in ledger.history] or [float("inf")]), "seconds": seconds}


# -- the tasks ---------------------------------------------------------------------------------------
@task(name="local", task_run_name="iteration-{iteration}-local", cache_policy=NO_CACHE)
def local_task(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray,
               start) -> dict:
    """Gauss-Newton with exact Jacobians from ``start`` (the nominal model), one FE run per round."""
    store = RunStore(root)
    logger = stages._logger()
    if stages._done(store, iteration, LOCAL_STAGE):
        return store.stage_info(iteration, LOCAL_STAGE)
    m = len(start)
    u = np.asarray(measured_amplitude, float).ravel()
    options = hybrid_options(config, m)
    lower, upper = _box(config, m)
    evaluator = StageEvaluator(store, config, iteration, LOCAL_STAGE, freqs_hz, m, _next_id(store, iteration), logger)
    ledger = _ledger(store, config, iteration - 1, evaluator, u, m)
    t0 = time.perf_counter()
    try:
        minimum = local_phase(ledger, np.asarray(start, float), lower, upper, options)
        minima, status = [minimum], minimum.status
    except BudgetSpent:
        minima, status = [], "budget"
    info = _phase_info(ledger, evaluator, minima, status, time.perf_counter() - t0)
    logger.info("iteration %d, stage local: %s after %d FE runs (%d with Jacobian) in %d rounds, best overall "
                "error %.4g %%", iteration, status, ledger.evaluations, ledger.jacobians, ledger.rounds,
                100 * info["best_error"])
    return evaluator.write(u, info)


@task(name="global", task_run_name="iteration-{iteration}-global", cache_policy=NO_CACHE)
def global_task(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray,
                minima) -> dict:
    """One global cycle: space-filling round, emulator, parallel Gauss-Newton runs away from ``minima``."""
    store = RunStore(root)
    logger = stages._logger()
    if stages._done(store, iteration, GLOBAL_STAGE):
        return store.stage_info(iteration, GLOBAL_STAGE)
    m = len(minima[0])
    u = np.asarray(measured_amplitude, float).ravel()
    options = hybrid_options(config, m)
    lower, upper = _box(config, m)
    evaluator = StageEvaluator(store, config, iteration, GLOBAL_STAGE, freqs_hz, m, _next_id(store, iteration),
                               logger)
    ledger = _ledger(store, config, iteration - 1, evaluator, u, m)
    t0 = time.perf_counter()
    try:
        found = global_phase(ledger, lower, upper, [np.asarray(x, float) for x in minima], options, iteration - 1)
        status = found[0].status if found else "budget"
    except BudgetSpent:
        found, status = [], "budget"
    info = _phase_info(ledger, evaluator, found, status, time.perf_counter() - t0)
    logger.info("iteration %d, stage global: %s after %d FE runs (%d with Jacobian) in %d rounds, best overall "
                "error %.4g %%", iteration, status, ledger.evaluations, ledger.jacobians, ledger.rounds,
                100 * info["best_error"])
    return evaluator.write(u, info)


@task(name="check", task_run_name="iteration-{iteration}-check", cache_policy=NO_CACHE)
def check_task(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray) -> dict:
    """Noise or structure at the best minimum of this cycle's stage (``fe_core.residual``)."""
    store = RunStore(root)
    if stages._done(store, iteration, CHECK_STAGE):
        return store.stage_info(iteration, CHECK_STAGE)
    stage = LOCAL_STAGE if store.is_finished(iteration, LOCAL_STAGE) else GLOBAL_STAGE
    info = store.stage_info(iteration, stage)
    u = np.asarray(measured_amplitude, float).ravel()
    m = len(info["minima"][0]["x"]) if info["minima"] else 0
    out = {"stage": stage, "at_floor": False, "reason": f"{stage} stage ended without a minimum ({info['status']})",
           "status": info["status"], "minimum": None}
    if info["minima"]:
        best = info["minima"][0]
        runs = store.read_table(iteration, stage, "runs")
        responses = store.read_table(iteration, stage, "responses")
        ok = runs[runs["status"] == "ok"]
        X = ok[stages.param_columns(m)].to_numpy()
        sid = int(ok["sample_id"].to_numpy()[int(np.argmin(np.max(np.abs(X - np.array(best["x"])), axis=1)))])
        part = responses[responses["sample_id"] == sid].sort_values(["frequency_hz", "sensor"], kind="stable")
        Z = part["real"].to_numpy() + 1j * part["imag"].to_numpy()
        verdict = check(Z, u, np.asarray(freqs_hz, float), m, hybrid_options(config, m))
        out.update({"at_floor": bool(verdict.at_floor or best["status"] == "target"), "reason": verdict.reason,
                    "rms": verdict.rms, "sigma": verdict.sigma if np.isfinite(verdict.sigma) else None,
                    "sigma_source": verdict.sigma_source, "p_chi2": verdict.p_chi2, "minimum": best})
    table = pd.DataFrame({"at_floor": [out["at_floor"]], "reason": [out["reason"]]})
    store.write_table(iteration, CHECK_STAGE, CHECK_STAGE, table)
    store.finish(iteration, CHECK_STAGE, [CHECK_STAGE], out)
    stages._logger().info("iteration %d, stage check: %s (%s)", iteration,
                          "at the floor" if out["at_floor"] else "structure left: global search", out["reason"])
    return store.stage_info(iteration, CHECK_STAGE)


def _next_id(store: RunStore, iteration: int) -> int:
    """The first sample id of cycle ``iteration``'s FE stage: after every earlier stage's runs."""
    runs, _ = all_runs(store, iteration - 1)
    return int(runs["sample_id"].max()) + 1 if len(runs) else 0
