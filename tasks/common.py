"""Helpers every stage module shares: the logger, "finished earlier?", and finishing a stage.

The strategies' task modules (``tasks/paper.py``, ``tasks/hybrid.py``, ``tasks/polish.py``,
``tasks/intervals.py``) import these, :mod:`tasks.fe_runs` and :mod:`tasks.record`, never each other.
"""

from __future__ import annotations

import logging

from tasks.runstore import RunStore

__all__ = ["logger", "done", "finish", "fitted"]

log = logging.getLogger("tasks")


def logger():
    """Prefect's run logger inside a run (shown in the UI), the module logger outside."""
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:
        return log


def done(store: RunStore, iteration: int, stage: str) -> bool:
    """Whether the stage finished earlier (record present, checksums intact); says so in the log."""
    if store.is_finished(iteration, stage):
        logger().info("iteration %d, stage %s: finished earlier, read back", iteration, stage)
        return True
    return False


def finish(store: RunStore, iteration: int, stage: str, names: list[str], info: dict,
           order: tuple[str, ...] = ()) -> None:
    """Record a stage as finished; if it replaced a different earlier result, the stages after it in
    ``order`` (and the summary) are stale and removed."""
    if store.finish(iteration, stage, names, info) and order:
        store.invalidate_after(iteration, stage, order)


def fitted(data):
    """(:class:`~mrgp_core.strategies.gauss_newton.Residual`, :class:`~mrgp_core.strategies.hybrid.Layout`) of a
    run's data: its residual of the receptance at the kept values (``data.cells``, frequency-major) and where
    those values sit."""
    import numpy as np

    from mrgp_core.strategies.gauss_newton import Residual
    from mrgp_core.strategies.hybrid import Layout

    line, channel = data.cells
    zeta = data.complex_frf[line, channel] if data.residual == "complex" else None
    return (Residual(data.amplitude[line, channel], zeta),
            Layout(np.asarray(data.frequencies_hz, float), line, channel))
