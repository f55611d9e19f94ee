"""The hybrid strategy as Prefect subflows (``python -m flows.update``, the default strategy).

Cycle 1 (subflow ``cycle-1``): ``local`` (Gauss-Newton from the nominal model with exact Jacobians) then
``check`` (is what is left noise?). While the check finds structure and the budget lasts, cycle k
(``cycle-<k>``): ``global`` (space-filling round, MRGP emulator, parallel Gauss-Newton runs) then
``check``. The strategy's pieces are :mod:`strategies.hybrid`, its tasks :mod:`tasks.hybrid`.

Wrong basin or missing effect (issue 28, :mod:`tasks.evidence`): when cycle 1's check finds structure, the
effect library is screened at the nominal model and at the local fit (stage ``evidence``); when the first global
round's check finds structure too, the library is screened at its best basin and the best effect is weighed
against the best basin found (stage ``weigh``):
``closure`` ends the search for basins (the run reports the screened point, where the closure should start:
``--close-loop`` or ``python -m flows.diagnose``), ``basins`` lets the cycles go on. ``summary.json`` has the
decision under ``evidence``.
"""

from __future__ import annotations

from prefect import flow

from tasks import evidence as evidence_tasks
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
    checks: list = []
    iteration = 0
    evidence, decision = None, None
    while True:
        iteration += 1
        last = cycle_flow(root, problem, config, iteration, minima)
        minima += [mn["x"] for mn in last["phase"]["minima"]]
        checks.append(last["check"])
        used = record.spent(store, iteration)
        if last["check"]["at_floor"] or not last["phase"]["minima"]:
            break
        if iteration == 1 and last["check"].get("minimum"):
            evidence = evidence_tasks.evidence_task(root, problem, config, iteration, last["check"]["minimum"]["x"])
        if iteration == 2 and evidence and evidence.get("screens"):
            decision = evidence_tasks.weigh_task(root, problem, config, iteration, evidence, checks)
            print(f"evidence: {decision['choice']}: {decision['reason']}")
            if decision["choice"] == "closure":
                break
        if last["phase"]["status"] == "budget":
            break
        if used["cost"] + config.s + tasks.JACOBIAN_COST >= config.max_fe_evaluations:
            break
    if decision is not None and decision["choice"] == "closure":
        return iteration, _to_closure(store, problem, iteration, last, evidence, decision)
    reported = record.best_run(record.fe_runs(store, iteration))
    at_best = None
    if last["check"].get("sample_id") != int(reported["sample_id"]):
        # The reported point is not where the last check looked (a later cycle found no better point, or none):
        # check the reported point itself, so that the stop reason and the convergence speak of it.
        at_best = tasks.check_point(store, problem, config, reported)
    reason, converged = stop_reason(iteration, last, reported, at_best)
    out = {**last, "stop_reason": reason, "converged": converged, "candidates": None}
    if evidence is not None:
        out["evidence"] = _evidence_summary(evidence, decision)
    return iteration, out


def _evidence_summary(evidence: dict, decision: dict | None) -> dict:
    """``summary.json``'s ``evidence``: the screens and the decision (None when no global round followed)."""
    screens = evidence.get("screens", []) if decision is None else decision.get("screens", [])
    screens = [{k: v for k, v in s.items() if k != "seconds"} for s in screens]  # wall time: in the stage records
    return {"screens": screens, "skipped": evidence.get("skipped", ""),
            "choice": None if decision is None else decision["choice"],
            "reason": "no global round with structure followed the screen" if decision is None else decision["reason"],
            "rss_effect": None if decision is None else decision["rss_effect"],
            "rss_basin": None if decision is None else decision["rss_basin"]}


def _to_closure(store: RunStore, problem, iteration: int, last: dict, evidence: dict, decision: dict) -> dict:
    """The outcome when a missing effect explains the residual far better than any basin: the reported point is
    the stored FE run where the best effect was screened (the nominal model or the local fit), where the closure
    starts."""
    import numpy as np

    runs = record.fe_runs(store, iteration)
    ok = runs[runs["status"] == "ok"]
    x = np.asarray(decision["best_screen"]["alpha"], float)
    sid = int(ok["sample_id"].to_numpy()[int(np.argmin(np.max(np.abs(ok[problem.names].to_numpy() - x), axis=1)))])
    reason = (f"cycle {iteration} (global): {last['phase']['status']}; evidence: {decision['reason']}; the reported "
              f"point is where the effect was screened ({decision['best_screen']['at']}, sample {sid}): run the "
              "closure from it (--close-loop, python -m flows.diagnose)")
    return {**last, "stop_reason": reason, "converged": False, "candidates": [sid],
            "evidence": _evidence_summary(evidence, decision)}


def stop_reason(iteration: int, last: dict, reported, at_best=None) -> tuple[str, bool]:
    """(why the run stopped, whether it converged): the last cycle's stage and check, or, when the reported
    point (``reported``: the best FE run, a row of the run record) is not the one the last check looked at, the
    check at the reported point (``at_best``: a :class:`strategies.hybrid.Check`)."""
    where = f"cycle {iteration} ({'local' if iteration == 1 else 'global'}): {last['phase']['status']}"
    if at_best is None:
        return f"{where}; check: {last['check']['reason']}", bool(last["check"]["at_floor"])
    return (f"{where}; the reported point, sample {int(reported['sample_id'])} of cycle {int(reported['iteration'])} "
            f"(overall error {reported['overall_error']:.4%}): {at_best.reason}", bool(at_best.at_floor))
