"""Helpers every stage module shares: the logger, "finished earlier?", and finishing a stage.

The stage modules (the one driver of every strategy, ``tasks/driver.py``; ``tasks/intervals.py``; the modal
stages) import these, :mod:`tasks.fe_runs` and :mod:`tasks.record`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time

from tasks.runstore import RunStore

__all__ = ["logger", "done", "finish", "heartbeat", "beating", "HEARTBEAT_ENV"]

#: Environment variable: seconds between the "still running" lines of a long stage (default 30; tests set less).
HEARTBEAT_ENV = "MRGP_HEARTBEAT_SECONDS"

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


@contextlib.contextmanager
def heartbeat(label: str, status=None, every: float | None = None):
    """Log ``<label>: still running, <elapsed> s[, <status()>]`` every ``every`` seconds while the block runs.

    For stages that can take minutes without a line of their own (a closure's fits and checks, an emulator's
    training, the intervals' posterior): the log shows at least one line a minute, with what is done so far
    (``status``: a callable giving e.g. ``"check 3 of 8 done"``). Default ``every``: ``$MRGP_HEARTBEAT_SECONDS``
    or 30 s.
    """
    every = float(every or os.environ.get(HEARTBEAT_ENV) or 30.0)
    log = logger()  # taken here: the run logger belongs to this thread's run context
    stop = threading.Event()
    t0 = time.perf_counter()

    def beat():
        while not stop.wait(every):
            extra = status() if status is not None else ""
            log.info("%s: still running, %.0f s%s", label, time.perf_counter() - t0, f", {extra}" if extra else "")

    thread = threading.Thread(target=beat, name=f"heartbeat {label}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def beating(label: str):
    """A task body under :func:`heartbeat` (decorate below ``@task``)."""
    import functools

    def wrap(fn):
        @functools.wraps(fn)
        def run(*args, **kwargs):
            with heartbeat(label):
                return fn(*args, **kwargs)
        return run
    return wrap
