"""The polish stage: local least squares on the FE model after the paper's MRGP loop (strategy ``adaptive``).

Runs :func:`strategies.polish.polish` from the loop's best FE run, inside the solver's box, with
the FE runs of each finite-difference Jacobian in parallel (:class:`tasks.fe_runs.FEStage`: each written as
soon as it finishes to ``iteration=<K>/stage=polish/sample=<id>.parquet`` and logged; the polish is
deterministic, so a resumed polish asks for the same points and reads their results back). When it ends,
the stage's run record (``runs.parquet``, ``responses.parquet``: :mod:`tasks.record`) is written and the
stage is recorded as finished.
"""

from __future__ import annotations

import time

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from strategies.polish import polish
from tasks import record
from tasks.common import done, logger
from tasks.fe_runs import FEStage
from tasks.runstore import RunStore

__all__ = ["POLISH_STAGE", "polish_task"]

POLISH_STAGE = "polish"


@task(name="polish", task_run_name="iteration-{iteration}-polish", cache_policy=NO_CACHE)
def polish_task(root: str, problem, config, iteration: int) -> dict:
    """Least squares on the FE model from the best FE run of iterations 1..``iteration``."""
    store = RunStore(root)
    log = logger()
    if done(store, iteration, POLISH_STAGE):
        return store.stage_info(iteration, POLISH_STAGE)
    data, m = problem.data, problem.m
    runs = record.fe_runs(store, iteration)
    best = record.best_run(runs)
    p, n = data.amplitude.shape
    Z0, _ = record.grid(record.responses(store, iteration, [best["sample_id"]]), p, n, m)
    x0, r0, e0 = best[problem.names].to_numpy(float), data.residuals(Z0), float(best["overall_error"])
    lower, upper = problem.solver_box
    if config.polish_max_fe < m + 1:
        log.warning("polish_max_fe = %d is less than one Jacobian and a step (%d FE runs): the polish can do "
                    "nothing", config.polish_max_fe, m + 1)
    # The polish asks for its points in a deterministic sequence; the k-th new point is sample base + k.
    stage = FEStage(store, problem, config, iteration, POLISH_STAGE, log)
    state = {"next": record.next_sample_id(store, iteration), "best": e0}

    def evaluate(points: list[np.ndarray]) -> list[np.ndarray]:
        ids = list(range(state["next"], state["next"] + len(points)))
        state["next"] += len(points)
        out = []
        for df in stage.run(ids, points, [False] * len(points)):
            Z, _ = record.grid(df, p, n, m)
            out.append(data.residuals(Z))
        state["best"] = min([state["best"], *(float(np.mean(np.abs(r))) for r in out if np.all(np.isfinite(r)))])
        log.info("iteration %d, stage polish: %d FE runs, best overall error so far %.4g %%", iteration,
                 len(stage.rows), 100 * state["best"])
        return out

    t0 = time.perf_counter()
    result = polish(evaluate, x0, lower, upper, residuals0=r0, target=config.polish_target,
                    max_evaluations=config.polish_max_fe, stall_window=None if config.polish_stall_rtol > 0 else 0,
                    stall_rtol=config.polish_stall_rtol)
    seconds = time.perf_counter() - t0
    info = stage.write({"n": len(stage.rows), "status": result.status, "message": result.message,
                        "start_sample_id": int(best["sample_id"]), "error_before": e0,
                        "error_after": float(result.error), "seconds": seconds})
    log.info("iteration %d, stage polish: %s after %d FE runs, overall error %.4g %% -> %.4g %%", iteration,
             result.status, info["n"], 100 * e0, 100 * result.error)
    return info
