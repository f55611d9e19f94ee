"""Prefect tasks of the hybrid strategy (:mod:`strategies.hybrid`): local, check, global.

Stages (``HYBRID_STAGES``), cycle k being ``iteration=k``::

    iteration=1: local  -> check           (Gauss-Newton from the nominal model; noise or structure?)
    iteration=2: global -> check           (only if the check found structure; and so on)

The ``local`` and ``global`` stages drive one phase of the strategy (a generator of rounds,
:mod:`strategies.hybrid_phases`) with :func:`strategies.ledger.drive`; their FE runs go
through :class:`tasks.fe_runs.FEStage` (stored as they finish, the complex receptance with its exact
derivative where the phase asked for it; replayed on resume: the strategy is deterministic, so the k-th
request of a stage is sample ``base + k``). A finished stage writes the run record's ``runs`` and
``responses`` (:mod:`tasks.record`); its record holds the minima it ended at and its counts.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from strategies.hybrid import BudgetSpent, HybridOptions, Ledger, check, global_phase, local_phase
from strategies.ledger import drive
from tasks import record
from tasks.common import done, heartbeat, logger
from tasks.fe_runs import JACOBIAN_COST, FEStage
from tasks.problem import black_box
from tasks.runstore import RunStore

__all__ = ["HYBRID_STAGES", "LOCAL_STAGE", "GLOBAL_STAGE", "CHECK_STAGE", "hybrid_options", "local_task",
           "global_task", "check_task", "check_point", "JACOBIAN_COST", "RERUNNABLE"]

LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE = "local", "global", "check"
HYBRID_STAGES = (LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE)
#: Stages a rerun recomputes from their stored inputs (``python -m flows.update rerun``): the FE stages replay
#: their stored FE runs where the rerun asks for the same points.
RERUNNABLE = (LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE)


#: A budget that follows the evidence: a phase still running when ``max_fe_evaluations`` is spent goes on while its
#: rounds improve its best error (:meth:`strategies.ledger.Ledger.admit`), up to this factor times the
#: budget (600 FE-run equivalents for the plain command's 240; docs/closure-far-off.md).
CAP_FACTOR = 2.5


def hybrid_options(config, problem=None) -> HybridOptions:
    """The strategy's settings from the run's config (keys documented in flows/config.py); a black-box model's
    Jacobian costs its m + 1 forward-difference runs."""
    budget = float(config.max_fe_evaluations)
    cost = problem.model.jacobian_cost if problem is not None and black_box(problem.model) else JACOBIAN_COST
    return HybridOptions(target=config.polish_target, noise=config.noise, max_cost=budget, cap=CAP_FACTOR * budget,
                         jacobian_cost=cost, space_filling=config.s, candidates=config.w,
                         starts=config.starts, trainer=config.trainer, seed=config.seed)


def _phase_ledger(store: RunStore, problem, config, iteration: int) -> Ledger:
    options = hybrid_options(config, problem)
    residual = problem.data
    used = record.spent(store, iteration - 1)
    ledger = Ledger(residual, options.max_cost - used["cost"], options.jacobian_cost,
                    cap=None if options.cap is None else options.cap - used["cost"],
                    improve_rounds=options.improve_rounds, improve_rtol=options.improve_rtol)
    runs = record.fe_runs(store, iteration - 1)
    if len(runs):
        data = problem.data
        line, channel = data.cells
        p, n = data.amplitude.shape
        ok = runs[runs["status"] == "ok"]
        by_sample = dict(tuple(record.responses(store, iteration - 1, ok["sample_id"]).groupby("sample_id",
                                                                                             sort=False)))
        for sid, x in zip(ok["sample_id"], ok[problem.names].to_numpy()):
            Z, _ = record.grid(by_sample[sid], p, n, problem.m)
            ledger.responses.append((x, Z[line, channel]))
    return ledger


def _minimum_info(minimum) -> dict:
    return {"x": [float(v) for v in minimum.x], "error": float(minimum.error), "status": minimum.status}


def _fe_stage(root: str, problem, config, iteration: int, stage: str, phase_of, output_stage: str | None = None
              ) -> dict:
    """Run one FE stage: ``phase_of(ledger, lower, upper, options)`` gives the phase generator; every FE run
    stored and replayed (:class:`tasks.fe_runs.FEStage`). ``output_stage``: another folder (a rerun)."""
    store = RunStore(root)
    out = output_stage or stage
    log = logger()
    if done(store, iteration, out):
        return store.stage_info(iteration, out)
    options = hybrid_options(config, problem)
    lower, upper = problem.solver_box
    ledger = _phase_ledger(store, problem, config, iteration)
    runner = FEStage(store, problem, config, iteration, out, log)
    if output_stage:  # a rerun reads the original stage's FE runs back where it asks for the same points
        runner.borrow(stage)
    state = {"next": record.next_sample_id(store, iteration - 1)}

    def evaluate(batch):
        ids = list(range(state["next"], state["next"] + len(batch)))
        state["next"] += len(batch)
        frames = runner.run(ids, batch.points, batch.jacobian)
        log.info("iteration %d, stage %s: round %d, %d FE runs (%d with Jacobian)", iteration, out, runner.rounds,
                 len(batch), sum(map(bool, batch.jacobian)))
        return runner.outcomes(frames, batch.jacobian)

    t0 = time.perf_counter()
    try:
        label = stage if stage == LOCAL_STAGE else f"{stage}-{iteration - 1}"
        with heartbeat(f"iteration {iteration}, stage {out}", lambda: f"{runner.rounds} rounds, {len(runner.rows)} "
                                                                      "FE runs so far"):
            minima = drive(phase_of(ledger, lower, upper, options), ledger, evaluate, label)
        minima = minima if isinstance(minima, list) else [minima]
        status = minima[0].status if minima else "budget"
    except BudgetSpent:
        minima, status = [], "budget"
    info = {"status": status, "minima": [_minimum_info(mn) for mn in minima], "extended_rounds": ledger.extended,
            "best_error": min([h[2] for h in ledger.history] or [float("inf")]), "seconds": time.perf_counter() - t0}
    info = runner.write(info)
    log.info("iteration %d, stage %s: %s after %d FE runs (%d with Jacobian) in %d rounds, best overall error "
             "%.4g %%", iteration, out, status, info["evaluations"], info["jacobians"], info["rounds"],
             100 * info["best_error"])
    return info


@task(name="local", task_run_name="iteration-{iteration}-local", cache_policy=NO_CACHE)
def local_task(root: str, problem, config, iteration: int, start, output_stage: str | None = None) -> dict:
    """Gauss-Newton with exact Jacobians from ``start`` (the nominal model), one FE run per round."""
    return _fe_stage(root, problem, config, iteration, LOCAL_STAGE,
                     lambda ledger, lo, hi, options: local_phase(ledger, np.asarray(start, float), lo, hi, options),
                     output_stage)


@task(name="global", task_run_name="iteration-{iteration}-global", cache_policy=NO_CACHE)
def global_task(root: str, problem, config, iteration: int, minima, output_stage: str | None = None) -> dict:
    """One global cycle: space-filling round, emulator, parallel Gauss-Newton runs away from ``minima``."""
    known = [np.asarray(x, float) for x in minima]
    return _fe_stage(root, problem, config, iteration, GLOBAL_STAGE,
                     lambda ledger, lo, hi, options: global_phase(ledger, lo, hi, known, options, iteration - 1),
                     output_stage)


def check_point(store: RunStore, problem, config, run):
    """The check (:func:`strategies.hybrid.check`) at one stored FE run (a row of the run record)."""
    data = problem.data
    p, n = data.amplitude.shape
    Z, _ = record.grid(record.responses(store, int(run["iteration"]), [int(run["sample_id"])]), p, n, problem.m)
    return check(data.kept(Z), data, problem.m, hybrid_options(config))


@task(name="check", task_run_name="iteration-{iteration}-check", cache_policy=NO_CACHE)
def check_task(root: str, problem, config, iteration: int, output_stage: str = CHECK_STAGE) -> dict:
    """Noise or structure at the best minimum of this cycle's stage (:func:`strategies.hybrid.check`)."""
    store = RunStore(root)
    if done(store, iteration, output_stage):
        return store.stage_info(iteration, output_stage)
    stage = LOCAL_STAGE if store.is_finished(iteration, LOCAL_STAGE) else GLOBAL_STAGE
    info = store.stage_info(iteration, stage)
    out = {"stage": stage, "at_floor": False, "reason": f"{stage} stage ended without a minimum ({info['status']})",
           "status": info["status"], "minimum": None}
    if info["minima"]:
        best = info["minima"][0]
        runs = store.read_table(iteration, stage, "runs")
        ok = runs[runs["status"] == "ok"]
        X = ok[problem.names].to_numpy()
        sid = int(ok["sample_id"].to_numpy()[int(np.argmin(np.max(np.abs(X - np.array(best["x"])), axis=1)))])
        data = problem.data
        p, n = data.amplitude.shape
        resp = store.read_table(iteration, stage, "responses")
        Z, _ = record.grid(resp[resp["sample_id"] == sid], p, n, problem.m)
        verdict = check(data.kept(Z), data, problem.m, hybrid_options(config))
        out.update({"sample_id": sid, "at_floor": bool(verdict.at_floor or best["status"] == "target"),
                    "reason": verdict.reason,
                    "rms": verdict.rms, "sigma": verdict.sigma if np.isfinite(verdict.sigma) else None,
                    "sigma_source": verdict.sigma_source, "p_chi2": verdict.p_chi2, "minimum": best,
                    "noise_config": config.noise})
    table = pd.DataFrame({"at_floor": [out["at_floor"]], "reason": [out["reason"]]})
    store.write_table(iteration, output_stage, CHECK_STAGE, table)
    store.finish(iteration, output_stage, [CHECK_STAGE], out)
    logger().info("iteration %d, stage check: %s (%s)", iteration,
                  "at the floor" if out["at_floor"] else "structure left: global search", out["reason"])
    return store.stage_info(iteration, output_stage)
