"""The hybrid strategy as Prefect subflows (``python -m flows.update``, the default strategy).

Cycle 1 (subflow ``cycle-1``): ``local`` (Gauss-Newton from the nominal model with exact Jacobians) then
``check`` (is what is left noise?). While the check finds structure and the budget lasts, cycle k
(``cycle-<k>``): ``global`` (space-filling round, MRGP emulator, parallel Gauss-Newton runs) then
``check``. The strategy's pieces are :mod:`mrgp_core.strategies.hybrid`, its tasks :mod:`tasks.hybrid`.
"""

from __future__ import annotations

from prefect import flow

from tasks import hybrid as tasks
from tasks import record
from tasks.runstore import RunStore

__all__ = ["cycle_flow", "run_hybrid", "stop_reason"]


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
    reported = record.best_run(record.fe_runs(store, iteration))
    at_best = None
    if last["check"].get("sample_id") != int(reported["sample_id"]):
        # The reported point is not where the last check looked (a later cycle found no better point, or none):
        # check the reported point itself, so that the stop reason and the convergence speak of it.
        at_best = tasks.check_point(store, problem, config, reported)
    reason, converged = stop_reason(iteration, last, reported, at_best)
    return iteration, {**last, "stop_reason": reason, "converged": converged, "candidates": None}


def stop_reason(iteration: int, last: dict, reported, at_best=None) -> tuple[str, bool]:
    """(why the run stopped, whether it converged): the last cycle's stage and check, or, when the reported
    point (``reported``: the best FE run, a row of the run record) is not the one the last check looked at, the
    check at the reported point (``at_best``: a :class:`mrgp_core.strategies.hybrid.Check`)."""
    where = f"cycle {iteration} ({'local' if iteration == 1 else 'global'}): {last['phase']['status']}"
    if at_best is None:
        return f"{where}; check: {last['check']['reason']}", bool(last["check"]["at_floor"])
    return (f"{where}; the reported point, sample {int(reported['sample_id'])} of cycle {int(reported['iteration'])} "
            f"(overall error {reported['overall_error']:.4%}): {at_best.reason}", bool(at_best.at_floor))
