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

from mrgp_core import adaptive
from tasks import hybrid as tasks
from tasks import stages
from tasks.runstore import RunStore

__all__ = ["cycle_flow", "run_hybrid", "hybrid_summary"]


@flow(name="cycle", flow_run_name="cycle-{iteration}", log_prints=True)
def cycle_flow(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray,
               start: list, minima: list) -> dict:
    """One cycle: the local (cycle 1) or global stage, then the check."""
    if iteration == 1:
        phase = tasks.local_task(root, config, iteration, freqs_hz, measured_amplitude, start)
    else:
        phase = tasks.global_task(root, config, iteration, freqs_hz, measured_amplitude, minima)
    verdict = tasks.check_task(root, config, iteration, freqs_hz, measured_amplitude)
    print(f"cycle {iteration}: {'local' if iteration == 1 else 'global'} {phase['status']}, best overall error "
          f"{phase['best_error']:.4%} after {phase['evaluations']} FE runs ({phase['jacobians']} with Jacobian) in "
          f"{phase['rounds']} rounds; check: {'floor' if verdict['at_floor'] else 'structure'}")
    return {"phase": phase, "check": verdict}


def run_hybrid(config, store: RunStore, measured, m: int) -> tuple[int, dict]:
    """All cycles of one run; returns (last cycle, its result)."""
    root = str(store.root)
    start = [0.0] * m  # the nominal model: every alpha_i = 0
    lower, upper = stages.parameter_box(config, m)
    start = list(np.clip(start, np.maximum(lower, -1.0 + 1e-3), upper))
    minima: list = []
    iteration = 0
    while True:
        iteration += 1
        last = cycle_flow(root, config, iteration, measured.frequencies_hz, measured.amplitude, start, minima)
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
    m = len([c for c in runs.columns if c.startswith("alpha_")])
    names = stages.param_columns(m)
    part = responses[responses["sample_id"] == best["sample_id"]].sort_values(["frequency_hz", "sensor"],
                                                                              kind="stable")
    amp = np.hypot(part["real"].to_numpy(), part["imag"].to_numpy()).reshape(measured.amplitude.shape)
    res = adaptive.relative_residuals(amp[None], measured.amplitude)[0]
    per_sensor = adaptive.per_sensor_error(res, measured.amplitude.shape[1])
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
