"""Prefect tasks of the hybrid's evidence (issue 28): wrong basin or missing effect?

Stages::

    iteration=1: evidence   (after the local fit's check found structure: the effect library screened at the
                             nominal model and at the local fit, :func:`fe_core.closure.evidence.screen_points`)
    iteration=2: weigh      (after the first global round's check found structure: the library screened at its
                             best basin too, the best effect against the best basin found,
                             :func:`fe_core.closure.evidence.weigh_round`)

The screens use the closure's measure (``ln(|Z| / u)`` on the lines where every channel is kept, the model seen
through the measured channels); a run whose data have several references, or that updates mass factors, is not
screened (the stage says why and the hybrid searches basins as before).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.closure.evidence import Screen, screen_points, weigh, weigh_round
from tasks import record
from tasks.common import done, logger
from tasks.problem import black_box
from tasks.runstore import RunStore

__all__ = ["EVIDENCE_STAGE", "WEIGH_STAGE", "evidence_task", "weigh_task", "screen_model"]

EVIDENCE_STAGE, WEIGH_STAGE = "evidence", "weigh"


def screen_model(problem):
    """(the model seen through the data's channels, "") when the effect library can be screened on the run's data
    (:func:`fe_core.closure.evidence.screen_points` on ``problem.data``), else (None, why not)."""
    data = problem.data
    if black_box(problem.model):
        return None, "not screened: the effects are terms of K and M, which a black-box solver deck does not expose"
    if problem.m != problem.model.n_segments:
        return None, "the run updates mass factors; the effect screen refits stiffness factors only"
    try:
        model = data.single_reference_model(problem.model)
    except ValueError as exc:
        return None, f"not screened: {exc}"
    if data.complete_lines.sum() < 3:
        return None, "not screened: fewer than three lines with every channel kept"
    return model, ""


@task(name="evidence", task_run_name="iteration-{iteration}-evidence", cache_policy=NO_CACHE)
def evidence_task(root: str, problem, config, iteration: int, local_x) -> dict:
    """The effect library screened at the nominal model and at the local fit ``local_x``."""
    store = RunStore(root)
    if done(store, iteration, EVIDENCE_STAGE):
        return store.stage_info(iteration, EVIDENCE_STAGE)
    t0 = time.perf_counter()
    model, why = screen_model(problem)
    screens = [] if model is None else screen_points(model, problem.data, {"nominal": problem.nominal,
                                                                           "local fit": np.asarray(local_x, float)})
    info = {"screens": [s.to_dict() for s in screens], "skipped": why, "seconds": time.perf_counter() - t0}
    table = pd.DataFrame({"at": [s.at for s in screens], "effect": [s.effect or "" for s in screens],
                          "location": [s.location or "" for s in screens], "rss": [s.rss for s in screens],
                          "rss_alpha": [s.rss_alpha for s in screens], "rss_effect": [s.rss_effect for s in screens]})
    store.write_table(iteration, EVIDENCE_STAGE, "screens", table)
    store.finish(iteration, EVIDENCE_STAGE, ["screens"], info)
    log = logger()
    for s in screens:
        log.info("iteration %d, stage evidence: %s", iteration, s.describe())
    if why:
        log.info("iteration %d, stage evidence: %s", iteration, why)
    return store.stage_info(iteration, EVIDENCE_STAGE)


def _sample_rss(store: RunStore, problem, iteration: int, sample_id: int) -> float:
    """Sum of squares of ``ln(|Z| / u)`` of one stored FE run on the complete lines (the screens' measure)."""
    data = problem.data
    p, n = data.amplitude.shape
    Z, _ = record.grid(record.responses(store, iteration, [int(sample_id)]), p, n, problem.m)
    return data.log_rss(data.kept(Z))


@task(name="weigh", task_run_name="iteration-{iteration}-weigh", cache_policy=NO_CACHE)
def weigh_task(root: str, problem, config, iteration: int, evidence: dict, checks: list) -> dict:
    """Missing effect or wrong basin: the screens of ``evidence`` against the best basin of the checks so far
    (``checks``: the check stages' records, each with the ``sample_id`` of its minimum)."""
    store = RunStore(root)
    if done(store, iteration, WEIGH_STAGE):
        return store.stage_info(iteration, WEIGH_STAGE)
    found = [c for c in checks if c.get("sample_id") is not None and c.get("minimum")]
    basins = {int(c["sample_id"]): _sample_rss(store, problem, iteration, c["sample_id"]) for c in found}
    screens = [Screen.from_dict(s) for s in evidence.get("screens", [])]
    model, _ = screen_model(problem)
    if found and model is not None:
        best = min(found, key=lambda c: basins[int(c["sample_id"])])
        decision, screens = weigh_round(model, problem.data, screens, best["minimum"]["x"],
                                        basins[int(best["sample_id"])])
    else:  # nothing to screen at: the screens so far against what re-fitting alpha alone leaves
        decision = weigh(screens, float("inf"))
    info = {**decision.to_dict(), "basins": {str(k): v for k, v in basins.items()},
            "screens": [s.to_dict() for s in screens]}
    store.write_table(iteration, WEIGH_STAGE, WEIGH_STAGE, pd.DataFrame({"choice": [decision.choice],
                                                                          "reason": [decision.reason]}))
    store.finish(iteration, WEIGH_STAGE, [WEIGH_STAGE], info)
    logger().info("iteration %d, stage weigh: %s: %s", iteration, decision.choice, decision.reason)
    return store.stage_info(iteration, WEIGH_STAGE)
