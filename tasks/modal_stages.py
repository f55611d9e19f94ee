"""Prefect tasks of the modal update (:mod:`flows.modal_update`), one core call each, every result stored.

Stages (``MODAL_STAGES``), all ``iteration=1`` of the run folder (:class:`tasks.runstore.RunStore`)::

    identifiable -> correlation_before -> [paper-1 .. paper-K] -> [fit-start-1 ..] fit -> correlation_after
    -> closure

The ``paper-<k>`` stages (``--strategy adaptive``/``paper`` only) are the paper loop's iterations, one each, run
by the one driver (:class:`tasks.driver.Driver`): its FE runs (parameters and residual vectors), and its steps
``paper-<k>-distribution``, ``-train``, ``-predict``, ``-select``; a resumed run replays them. The
``fit-start-<k>`` stages are the Gauss-Newton fit's evaluations from its start k (:mod:`tasks.modal_fit`), run by
the same driver and replayed likewise.

Each writes one table ``<stage>.parquet`` and its record ``_stage.json`` whose ``info`` holds the stage's
result (JSON); a resumed run (same inputs and settings, :func:`flows.preflight.check_resume`) reads a
finished stage back instead of computing it (no FE run). A stage recomputed with another result removes
the records of the stages after it (:func:`tasks.common.finish`).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from tasks import modal
from tasks.common import done, finish, logger
from tasks.runstore import RunStore

__all__ = ["MODAL_STAGES", "identifiable_notes", "record_identifiable", "correlation_task", "fit_task",
           "closure_task", "paper_task"]

MODAL_STAGES = ("identifiable", "correlation_before", "fit", "correlation_after", "closure")
ITERATION = 1


def _store(store: RunStore, stage: str, table: pd.DataFrame, info: dict) -> dict:
    store.write_table(ITERATION, stage, stage, table)
    finish(store, ITERATION, stage, [stage], info, MODAL_STAGES)
    return store.stage_info(ITERATION, stage)  # as a resume reads it (JSON types)


def identifiable_notes(store: RunStore, residual, names: list[str], source: str) -> list[str] | None:
    """The identifiability check's notes read back from a finished stage, else computed (raises
    :class:`~tasks.io.measured.MeasuredDataError` when refused; nothing is written here, so a refused run
    leaves no folder)."""
    if store.is_finished(ITERATION, "identifiable"):
        return None
    return modal.check_identifiable(residual, names, source)


def record_identifiable(store: RunStore, notes: list[str] | None) -> list[str]:
    if notes is None:
        logger().info("stage identifiable: finished earlier, read back")
        return store.stage_info(ITERATION, "identifiable")["notes"]
    return _store(store, "identifiable", pd.DataFrame({"note": pd.Series(notes, dtype=str)}), {"notes": notes})["notes"]


@task(name="correlation", task_run_name="{stage}", cache_policy=NO_CACHE)
def correlation_task(root: str, stage: str, data, model, theta, n_model: int, threshold: float) -> dict:
    """FE modes at ``theta`` against the measured ones (:func:`tasks.modal.correlate`)."""
    store = RunStore(root)
    if done(store, ITERATION, stage):
        return store.stage_info(ITERATION, stage)
    result = modal.correlate(data, model, np.asarray(theta, float), n_model, threshold)
    pairs = pd.DataFrame(result["pairs"], columns=["test", "model", "f_test_hz", "f_model_hz", "difference", "mac"])
    return _store(store, stage, pairs, result)


@task(name="fit", task_run_name="fit", cache_policy=NO_CACHE)
def fit_task(root: str, residual, lower, upper, starts: int, seed: int, stated: bool, x0=None) -> dict:
    """The modal update's Gauss-Newton fit under the one driver (:func:`tasks.modal_fit.run_fit`: each start's
    evaluations a stage ``fit-start-<k>``, replayed on a resume; every FE run to ``modal_runs.jsonl``); ``x0``
    the first start (the paper loop's best FE run; default the nominal model)."""
    from tasks.modal_fit import run_fit

    store = RunStore(root)
    if done(store, ITERATION, "fit"):
        return store.stage_info(ITERATION, "fit")
    t0 = time.perf_counter()
    fit, pairing, computed = run_fit(store, residual, lower, upper, starts, seed, stated, x0)
    info = {"theta": fit.theta, "sd": fit.sd, "lower95": fit.lower95, "upper95": fit.upper95,
            "covariance": fit.covariance, "chi2": fit.chi2, "n_residuals": fit.n_residuals, "scale2": fit.scale2,
            "starts": fit.starts, "fe_runs": fit.n_fe_runs, "jacobians": fit.n_jacobians,
            "evaluations_computed": computed, "seconds": time.perf_counter() - t0, "swaps": list(residual.swaps), "active": residual.active,
            "pairing": {k: pairing[k] for k in ("test", "model", "f_model", "mac")},
            "unpaired": pairing["unpaired"]}
    table = pd.DataFrame({"theta": fit.theta, "sd": fit.sd, "lower95": fit.lower95, "upper95": fit.upper95})
    return _store(store, "fit", table, info)


@task(name="closure", task_run_name="closure", cache_policy=NO_CACHE)
def closure_task(root: str, residual, theta, lower, upper, stated: bool, effects, active) -> dict:
    """Effects the model lacks, screened and checked on the modal residual
    (:func:`fe_core.modal_update.closure.modal_closure`)."""
    from fe_core.modal_update.closure import modal_closure

    store = RunStore(root)
    if done(store, ITERATION, "closure"):
        return store.stage_info(ITERATION, "closure")
    t0 = time.perf_counter()
    residual.active = np.asarray(active, int)  # the measured modes the fit used (read back on a resume)
    result = modal_closure(residual, np.asarray(theta, float), np.asarray(lower, float), np.asarray(upper, float),
                           stated=stated, effects=effects)
    result["seconds"] = time.perf_counter() - t0
    modal.write_runs(residual, store.root)  # the closure's FE runs (stages closure-<step>) with the others
    table = pd.DataFrame(result["candidates"], columns=["step", "effect", "location", "value", "unit",
                                                        "linear_drop", "chi2", "delta_bic"]).astype(
        {"chi2": float, "delta_bic": float})
    return _store(store, "closure", table, result)


class ModalEvaluations:
    """One stage of the modal paper loop's FE runs (eigen-solves) under the driver (:class:`tasks.driver.Driver`,
    the FE-stage interface): each point's modal residual row computed in this process
    (:func:`strategies.modal_paper.evaluate_row`, logged to ``modal_runs.jsonl``), the stage's table ``paper``
    (the points ``x<i>`` and rows ``r<j>``) written when the loop moves on and read back on a resume when the
    loop asks for the same points."""

    def __init__(self, store: RunStore, residual, iteration: int, stage: str, log, n_res: int):
        self.store, self.residual, self.iteration, self.stage, self.logger = store, residual, iteration, stage, log
        self.n_res, self.replay_only, self.stored = n_res, False, {}
        self.rows: list = []
        self.results: list = []
        self.rounds = self.ran = self.replayed = 0
        self.previous = None
        if store.is_finished(iteration, stage):
            table = store.read_table(iteration, stage, "paper")
            self.previous = (table[[c for c in table.columns if c.startswith("x")]].to_numpy(),
                             table[[c for c in table.columns if c.startswith("r")]].to_numpy())

    def run(self, ids, points, jacobian) -> list:
        from strategies.modal_paper import evaluate_row

        self.rounds += 1
        points = np.asarray(points, float)
        X, R = self.previous if self.previous is not None else (None, None)
        if X is not None and X.shape == points.shape and np.allclose(X, points, rtol=0, atol=1e-12):
            out = [np.asarray(r, float).astype(complex) for r in R]
            self.replayed += len(out)
        else:  # another loop's samples (settings are checked before): computed
            self.residual.label = self.stage
            out = [evaluate_row(self.residual, x, self.n_res).Z for x in points]
            self.ran += len(out)
            modal.write_runs(self.residual, self.store.root)
        self.rows += [(int(i), x) for i, x in zip(ids, points)]
        self.results += out
        return out

    def outcomes(self, frames, jacobian) -> list:
        from strategies.base import Outcome

        return [Outcome(z) for z in frames]

    def write(self, info: dict) -> dict:
        X = np.array([x for _, x in self.rows])
        R = np.real(np.array(self.results))
        table = pd.concat([pd.DataFrame(X, columns=[f"x{i}" for i in range(X.shape[1])]),
                           pd.DataFrame(R, columns=[f"r{i}" for i in range(R.shape[1])])], axis=1)
        self.store.write_table(self.iteration, self.stage, "paper", table)
        errors = np.mean(np.abs(R), axis=1)
        self.store.finish(self.iteration, self.stage, ["paper"], {
            "fe_runs": len(X), "best_error": float(np.nanmin(errors)), "evaluations": len(X), "ran_now": self.ran,
            **info})
        return self.store.stage_info(self.iteration, self.stage)


@task(name="paper", task_run_name="paper", cache_policy=NO_CACHE)
def paper_task(root: str, residual, lower, upper, options) -> dict:
    """The paper's MRGP loop on the modal residual (:func:`strategies.modal_paper.paper_loop`) under the one
    driver: iteration k's FE runs are stage ``paper-<k>`` (their parameters and residual rows), its steps
    ``paper-<k>-<step>`` (distribution, train, predict, select); a resume replays them (no eigen-solve, no MRGP
    training); every FE run computed goes to ``modal_runs.jsonl``."""
    from strategies.modal_paper import n_residuals, paper_loop
    from tasks.driver import Driver

    store = RunStore(root)
    t0 = time.perf_counter()
    residual.set_active(np.zeros(len(lower)))
    n_res, n_swaps = n_residuals(residual), len(residual.swaps)
    stages = []

    def evaluations(iteration, stage, log, modes, replay_only):
        stages.append(ModalEvaluations(store, residual, iteration, stage, log, n_res))
        return stages[-1]

    driver = Driver(store, None, None, None, make=lambda memo: paper_loop(residual, lower, upper, options, memo),
                    stages=evaluations, where=lambda k, s: (ITERATION, f"paper-{k}" if s == "fe" else f"paper-{k}-{s}"))
    driver.run()
    residual.label = "fit"
    del residual.swaps[n_swaps:]  # pairings of scattered samples differ by nature: no path to track a swap along
    loop = driver.strategy
    x, e = loop.best()
    decision = loop.stop()
    info = {"best": x, "best_error": e, "threshold": loop.options.threshold, "iterations": loop.iteration,
            "fe_runs": int(sum(len(h[1]) for h in loop.history)), "fe_runs_computed": int(sum(s.ran for s in stages)),
            "per_iteration": [{"iteration": k, "fe_runs": len(X), "best_error": float(np.min(E)) if len(E) else None}
                              for k, X, E in loop.history],
            "converged": decision.converged, "seconds": time.perf_counter() - t0,
            # the loop's rule words errors as percentages (relative FRF errors); a modal residual is in sd units
            "reason": (f"at the noise (best mean |r| {e:.3f} <= {loop.options.threshold:.3f})" if decision.converged
                       else decision.reason)}
    logger().info("paper loop on the modal residual: %s after %d iterations, %d FE runs, best mean |r| %.3f",
                  decision.reason, loop.iteration, info["fe_runs"], e)
    return info
