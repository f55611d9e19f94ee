"""The hybrid strategy as Prefect subflows (``python -m flows.update``, the default strategy).

Cycle 1 (subflow ``cycle-1``): ``local`` (Gauss-Newton from the nominal model with exact Jacobians) then
``check`` (is what is left noise?). While the check finds structure and the budget lasts, cycle k
(``cycle-<k>``): ``global`` (space-filling round, MRGP emulator, parallel Gauss-Newton runs) then
``check``. The strategy's pieces are :mod:`mrgp_core.strategies.hybrid`, its tasks :mod:`tasks.hybrid`.
"""

from __future__ import annotations

import numpy as np
from prefect import flow

from tasks import hybrid as tasks
from tasks import record
from tasks.runstore import RunStore

__all__ = ["cycle_flow", "run_hybrid", "run_history"]


@flow(name="cycle", flow_run_name="cycle-{iteration}", log_prints=True)
def cycle_flow(root: str, problem, config, iteration: int, minima: list) -> dict:
    """One cycle: the local (cycle 1) or global stage, then the check."""
    if iteration == 1:
        phase = tasks.local_task(root, problem, config, iteration, list(problem.nominal))
    else:
        phase = tasks.global_task(root, problem, config, iteration, minima)
    verdict = tasks.check_task(root, problem, config, iteration)
    print(f"cycle {iteration}: {'local' if iteration == 1 else 'global'} {phase['status']}, best overall error "
          f"{phase['best_error']:.4%} after {phase['evaluations']} FE runs ({phase['jacobians']} with Jacobian) in "
          f"{phase['rounds']} rounds; check: {'floor' if verdict['at_floor'] else 'structure'}")
    return {"phase": phase, "check": verdict}


def run_hybrid(problem, config, store: RunStore) -> tuple[int, dict]:
    """All cycles of one run; returns (last cycle, outcome) with ``outcome["stop_reason"]`` and
    ``outcome["converged"]`` (the last check found the floor)."""
    root = str(store.root)
    minima: list = []
    iteration = 0
    while True:
        iteration += 1
        last = cycle_flow(root, problem, config, iteration, minima)
        minima += [mn["x"] for mn in last["phase"]["minima"]]
        used = record.spent(store, iteration)
        if last["check"]["at_floor"] or not last["phase"]["minima"] or last["phase"]["status"] == "budget":
            break
        if used["cost"] + config.s + tasks.JACOBIAN_COST >= config.max_fe_evaluations:
            break
    verdict = last["check"]
    reason = (f"cycle {iteration} ({'local' if iteration == 1 else 'global'}): {last['phase']['status']}; "
              f"check: {verdict['reason']}")
    return iteration, {**last, "stop_reason": reason, "converged": bool(verdict["at_floor"]), "candidates": None}


def run_history(store, iterations: int | None = None) -> list[dict]:
    """Every FE run of a run in evaluation order: ``round`` (counted over the whole run), ``x``, ``error``
    (overall error, inf for a failed run), ``jacobian``, ``cost`` (FE-run equivalents). ``store``: a
    :class:`RunStore` or the run folder; any strategy's run (the paper loop's iterations are one round each)."""
    store = store if isinstance(store, RunStore) else RunStore(store)
    runs = record.fe_runs(store, iterations)
    names = record.parameter_columns(runs)
    out, offset = [], 0
    order = {s: i for i, s in enumerate(record.FE_STAGE_ORDER)}
    for (k, _, stage), g in runs.assign(rank=runs["stage"].map(order)).groupby(["iteration", "rank", "stage"],
                                                                              sort=True):
        for row in g.sort_values("sample_id").itertuples(index=False):
            d = row._asdict()
            out.append({"round": offset + int(d["round"]), "x": np.array([d[n] for n in names], float),
                        "error": float(d["overall_error"]) if d["status"] == "ok" else float("inf"),
                        "jacobian": bool(d["jacobian"]), "cost": float(d["cost"])})
        offset += int(store.stage_info(int(k), stage)["rounds"])
    return out
