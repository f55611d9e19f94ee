"""The hybrid strategy as Prefect subflows (``python -m flows.update``, the default strategy).

Cycle 1 (subflow ``cycle-1``): ``local`` (Gauss-Newton from the nominal model
with exact Jacobians) then ``check`` (is what is left noise?). While the check
finds structure and the budget lasts, cycle k (``cycle-<k>``): ``global``
(space-filling round, MRGP emulator, parallel Gauss-Newton runs) then
``check``. Then the intervals stage and the summary. The pure strategy is
:mod:`mrgp_core.strategies.hybrid`, its tasks :mod:`tasks.hybrid`.
"""

from __future__ import annotations

import numpy as np
from prefect import flow

from tasks import hybrid as tasks
from tasks import stages
from tasks.runstore import RunStore

__all__ = ["cycle_flow", "run_hybrid", "hybrid_summary"]


@flow(name="cycle", flow_run_name="cycle-{iteration}", log_prints=True)
def cycle_flow(root: str, config, iteration: int, data, start: list, minima: list) -> dict:
    """One cycle: the local (cycle 1) or global stage, then the check; ``data`` the run's UpdateData."""
    if iteration == 1:
        phase = tasks.local_task(root, config, iteration, data, start)
    else:
        phase = tasks.global_task(root, config, iteration, data, minima)
    verdict = tasks.check_task(root, config, iteration, data)
    print(f"cycle {iteration}: {'local' if iteration == 1 else 'global'} {phase['status']}, best overall error "
          f"{phase['best_error']:.4%} after {phase['evaluations']} FE runs ({phase['jacobians']} with Jacobian) in "
          f"{phase['rounds']} rounds; check: {'floor' if verdict['at_floor'] else 'structure'}")
    return {"phase": phase, "check": verdict}


def run_hybrid(config, store: RunStore, data, m: int) -> tuple[int, dict]:
    """All cycles of one run (``data``: the run's :class:`tasks.update_data.UpdateData`); returns (last cycle,
    its result)."""
    root = str(store.root)
    start = [0.0] * m  # the nominal model: every factor 0
    start = list(np.clip(start, *stages.solver_box(config, m)))
    minima: list = []
    iteration = 0
    while True:
        iteration += 1
        last = cycle_flow(root, config, iteration, data, start, minima)
        minima += [mn["x"] for mn in last["phase"]["minima"]]
        used = tasks.spent(store, iteration)
        if last["check"]["at_floor"] or not last["phase"]["minima"] or last["phase"]["status"] == "budget":
            return iteration, last
        if used["cost"] + config.s + tasks.JACOBIAN_COST >= config.max_fe_evaluations:
            return iteration, last


def hybrid_summary(config, store: RunStore, iterations: int, last: dict, measured, wall: float) -> dict:
    """``summary.json`` of a hybrid run (the keys of the adaptive strategy's, plus Jacobians and rounds)."""
    runs, responses = tasks.all_runs(store, iterations)
    ok = runs[runs["status"] == "ok"]
    best = ok.loc[ok["overall_error"].idxmin()]
    names = stages.parameter_names(config)
    p, n = measured.amplitude.shape
    Z, _ = tasks._grid(responses[responses["sample_id"] == best["sample_id"]], p, n, len(names))
    per_sensor = measured.channel_errors(measured.residuals(Z))
    used = tasks.spent(store, iterations)
    verdict = last["check"]
    summary = {
        "parameters": {n: float(best[n]) for n in names},
        "overall_error": float(best["overall_error"]),
        "per_sensor_error": {f"sensor_{int(s)}": float(v) for s, v in zip(measured.sensors, per_sensor)},
        "fe_evaluations": int(used["evaluations"]),
        "jacobians": int(used["jacobians"]),
        "fe_equivalents": float(used["cost"]),
        "jacobian_cost": tasks.JACOBIAN_COST,
        "residual": measured.residual,
        "rounds": int(used["rounds"]),
        "iterations": iterations,
        "converged": bool(verdict["at_floor"]),
        "stop_reason": (f"cycle {iterations} ({'local' if iterations == 1 else 'global'}): {last['phase']['status']}; "
                        f"check: {verdict['reason']}"),
        "trainer": config.trainer,
        "strategy": config.strategy,
        "seed": config.seed,
        "best_sample_id": int(best["sample_id"]),
        "wall_seconds": round(wall, 3),
        "run_folder": str(store.root),
    }
    if config.true_parameters is not None:
        truth = np.asarray(config.true_parameters, float)
        summary["parameter_errors"] = {n: float(abs(best[n] - t)) for n, t in zip(names, truth)}
    return summary


def run_history(store: RunStore, iterations: int) -> list[dict]:
    """Every FE run of a hybrid run in evaluation order: ``round`` (counted over the whole run), ``x``,
    ``error`` (overall error, inf for a failed run), ``jacobian``, ``cost`` (FE-run equivalents)."""
    runs, _ = tasks.all_runs(store, iterations)
    out, offset = [], 0
    names = stages.parameter_names(_config_of(store))
    for (k, stage), g in runs.groupby(["iteration", "stage"], sort=True):
        for row in g.sort_values("sample_id").itertuples(index=False):
            d = row._asdict()
            out.append({"round": offset + int(d["round"]), "x": np.array([d[n] for n in names], float),
                        "error": float(d["overall_error"]) if d["status"] == "ok" else float("inf"),
                        "jacobian": bool(d["jacobian"]), "cost": float(d["cost"])})
        offset += int(store.stage_info(int(k), stage)["rounds"])
    return out


def _config_of(store: RunStore):
    from flows.config import UpdateConfig, stored_settings

    return UpdateConfig(**stored_settings(store.read_manifest()["config"]))
