"""The paper's loop as Prefect subflows (strategies ``adaptive`` and ``conventional``).

Each iteration is a subflow ``iteration-<k>`` with the tasks
``samples -> fe -> errors -> (stop?) -> distribution -> train -> predict -> select`` (:mod:`tasks.paper`,
each wrapping one step of :mod:`strategies.paper`); the adaptive strategy then hands the best
sample to the polish (:mod:`tasks.polish`) unless ``polish = false`` (the paper's procedure alone).
"""

from __future__ import annotations

from prefect import flow

from strategies import paper as steps
from tasks import paper as tasks
from tasks import record
from tasks.polish import polish_task
from tasks.runstore import RunStore

__all__ = ["iteration_flow", "run_paper"]


@flow(name="iteration", flow_run_name="iteration-{iteration}", log_prints=True)
def iteration_flow(root: str, problem, config, iteration: int) -> dict:
    """One iteration: FE batch and errors, then (unless stopping) the next batch."""
    tasks.samples_task(root, problem, config, iteration)
    tasks.fe_task(root, problem, config, iteration)
    tasks.errors_task(root, problem, config, iteration)
    store = RunStore(root)
    _, _, _, errors = tasks.training_data(store, iteration)
    fe_count = tasks.fe_count(store, iteration)
    best = float(errors.min()) if errors.size else float("inf")
    decision = steps.stop(tasks.paper_options(config), iteration, best, fe_count)
    if decision.stop:
        return {"stop": True, "converged": decision.converged, "reason": decision.reason, "best": best,
                "fe": fe_count}
    tasks.distribution_task(root, problem, config, iteration)
    tasks.train_task(root, problem, config, iteration)
    tasks.predict_task(root, problem, config, iteration)
    tasks.select_task(root, problem, config, iteration)
    print(f"iteration {iteration}: best overall error {best:.4%} after {fe_count} FE runs")
    return {"stop": False, "converged": False, "reason": "continue", "best": best, "fe": fe_count}


def run_paper(problem, config, store: RunStore) -> tuple[int, dict]:
    """All iterations of one run, then the polish (adaptive strategy); returns (last iteration, outcome) with
    ``outcome["stop_reason"]``."""
    root = str(store.root)
    iteration = 0
    while True:
        iteration += 1
        last = iteration_flow(root, problem, config, iteration)
        if last["stop"]:
            break
    reason = last["reason"]
    if tasks.uses_polish(config):
        info = polish_task(root, problem, config, iteration)
        print(f"polish: {info['status']} after {info['n']} FE runs, overall error "
              f"{info['error_before']:.4%} -> {info['error_after']:.4%}")
        reason = f"MRGP loop: {reason}; polish: {info['status']} after {info['n']} FE runs ({info['message']})"
        last = {**last, "polish": {k: info[k] for k in ("status", "n", "error_before", "error_after")}}
    candidates = _candidates(store, config, iteration)
    runs = record.fe_runs(store, iteration)
    pool = runs if candidates is None else runs[runs["sample_id"].isin(candidates)]
    converged = bool(record.best_run(pool)["overall_error"] <= config.threshold)
    return iteration, {**last, "stop_reason": reason, "candidates": candidates, "converged": converged}


def _candidates(store: RunStore, config, iteration: int):
    """The FE runs the reported result is chosen from: all of them, but for the conventional baseline only
    the final batch (its one MRGP's best prediction)."""
    runs = record.fe_runs(store, iteration)
    if config.strategy == "conventional":
        final = set(store.read_table(iteration, "samples")["sample_id"])
        picked = runs[runs["sample_id"].isin(final) & (runs["status"] == "ok")]
        if len(picked):
            return picked["sample_id"].tolist()
    return None
