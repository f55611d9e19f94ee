"""The intervals stage: 95 % intervals and the covariance of the updated parameters.

After the polish, :func:`fe_core.intervals.parameter_intervals` takes
Gauss-Newton steps with the exact Jacobian (Krylov, with its FRF) from the run's best
parameters to the least-squares optimum of the log-amplitude residual and
computes the Laplace intervals there (noise from ``config.noise`` or
estimated from the residual). Written to
``iteration=<K>/stage=intervals/intervals.parquet`` (one row per parameter:
estimate, interval, standard deviation, the covariance row) with the summary
fields in the stage record; a resumed run reads them back unless ``noise``
changed (the only setting a resume may change that the intervals depend on).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.intervals import parameter_intervals
from tasks import stages
from tasks.polish import polish_lower_bound
from tasks.runstore import RunStore

__all__ = ["INTERVALS_STAGE", "intervals_task"]

INTERVALS_STAGE = "intervals"


@task(name="intervals", task_run_name="iteration-{iteration}-intervals", cache_policy=NO_CACHE)
def intervals_task(root: str, config, iteration: int, freqs_hz: np.ndarray, measured_amplitude: np.ndarray,
                   start) -> dict:
    """Intervals near ``start`` (shape (m,), the run's best parameters); returns the stage record's info.

    The info holds the ``summary.json`` fields (``intervals``, ``covariance``,
    ``interval_method``, ``noise_sigma``, ``interval_details``) and the cost
    (``interval_cost``: Jacobians, FE runs besides them, seconds; the flow adds the
    cost in FE runs of the update).
    """
    store = RunStore(root)
    logger = stages._logger()
    if store.is_finished(iteration, INTERVALS_STAGE):
        info = store.stage_info(iteration, INTERVALS_STAGE)
        if info.get("noise_config") == config.noise:
            logger.info("iteration %d, stage intervals: finished earlier, read back", iteration)
            return info
        logger.info("iteration %d, stage intervals: noise changed from %s to %s, computed again", iteration,
                    info.get("noise_config"), config.noise)
    model = stages.load_model(config.model)
    m = model.n_segments
    lower, upper = stages.parameter_box(config, m)
    lower = np.maximum(lower, polish_lower_bound(-1.0))
    t0 = time.perf_counter()
    refined = parameter_intervals(model, freqs_hz, measured_amplitude, np.asarray(start, float), lower, upper,
                                  noise=config.noise)
    seconds = time.perf_counter() - t0
    iv = refined.intervals
    cols = stages.param_columns(m)
    table = pd.DataFrame({"parameter": cols, "start": refined.start, "estimate": iv.estimate, "low": iv.low,
                          "high": iv.high, "std": iv.std, "unpinned": iv.unpinned, "near_bound": iv.near_bound})
    for j, c in enumerate(cols):
        table[f"cov_{c}"] = iv.covariance[:, j]
    store.write_table(iteration, INTERVALS_STAGE, INTERVALS_STAGE, table)
    info = {**iv.to_summary(), "noise_config": config.noise,
            "interval_cost": {"fe_runs": refined.fe_runs, "jacobians": refined.jacobians,
                              "seconds": round(seconds, 3), "at_optimum": refined.at_optimum,
                              "last_step_in_std": (refined.last_step_in_std if np.isfinite(refined.last_step_in_std)
                                                   else None)}}
    store.finish(iteration, INTERVALS_STAGE, [INTERVALS_STAGE], info)
    logger.info("iteration %d, stage intervals: %s noise %.3g %%, %d exact Jacobians with their FRF (%.2f s)",
                iteration, iv.noise_source, 100 * iv.noise_sigma, refined.jacobians, seconds)
    for line in iv.flag_lines():
        logger.warning(line)
    return store.stage_info(iteration, INTERVALS_STAGE)
