"""Where the FE stage's runs execute: loky processes on this machine, or a Dask cluster.

``fe_backend = "loky"`` (the default) runs ``n_jobs`` joblib worker processes
on this machine. ``fe_backend = "dask"`` sends the FE runs to the workers of a
running ``distributed`` scheduler at ``dask_address`` (``tcp://host:8786``),
through joblib's Dask backend; ``n_jobs`` is then ignored (every worker thread
of the cluster takes FE runs). The workers must be able to import this project
(same code, same environment as the flow) and, like the flow, should run one
BLAS thread each (``dask worker`` started through a nanny sets
``OMP_NUM_THREADS=1`` and friends itself).

Both backends hand results back in completion order, so the FE stage writes
each result as soon as it arrives.

Loss of a worker:

- Dask reschedules the tasks of a dead worker by itself (and a nanny restarts
  the worker); the stage sees nothing unless a task has killed
  ``distributed.scheduler.allowed-failures`` workers in a row
  (:class:`distributed.KilledWorker`).
- loky raises ``TerminatedWorkerError`` (a ``BrokenProcessPool``) and drops the
  runs in flight.

In both failure cases :func:`run_unordered` submits again the calls whose result
has not been handed out yet (results already handed out, i.e. written by the
FE stage, are kept), at most :data:`WORKER_LOSS_RETRIES` times, logging why.
"""

from __future__ import annotations

import contextlib
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator

from joblib import Parallel, parallel_config

__all__ = [
    "FE_BACKENDS",
    "WORKER_LOSS_RETRIES",
    "FEBackendError",
    "worker_lost_errors",
    "connect",
    "check_dask",
    "fe_parallel",
    "run_unordered",
]

FE_BACKENDS = ("loky", "dask")

#: Re-submissions of the missing FE runs after a lost worker, per stage call.
WORKER_LOSS_RETRIES = 3

#: Seconds to wait for a Dask scheduler to answer.
CONNECT_TIMEOUT = 10.0


class FEBackendError(RuntimeError):
    """An FE backend that cannot be used; the message names the setting and the cause."""


def worker_lost_errors() -> tuple[type[BaseException], ...]:
    """Exceptions meaning "a worker died and took FE runs with it" (re-submission helps)."""
    errors: list[type[BaseException]] = [BrokenProcessPool]  # loky's TerminatedWorkerError is one
    try:
        from distributed import KilledWorker
    except ImportError:
        pass
    else:
        errors.append(KilledWorker)
    return tuple(errors)


def connect(address: str | None, timeout: float | None = None):
    """A ``distributed.Client`` of the scheduler at ``address`` (not made the default client).

    Raises
    ------
    FEBackendError
        dask/distributed not installed, no address, or no scheduler answering.
    """
    try:
        from distributed import Client
    except ImportError as exc:
        raise FEBackendError("fe_backend 'dask' needs the packages dask and distributed: "
                             "pip install -e '.[dask]'") from exc
    if not address:
        raise FEBackendError("fe_backend 'dask' needs dask_address, the scheduler's address "
                             "(--dask-address tcp://HOST:8786)")
    timeout = CONNECT_TIMEOUT if timeout is None else timeout
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise FEBackendError(
            f"dask_address {address!r}: no Dask scheduler answered within {timeout:g} s ({exc}); "
            f"start one with `dask scheduler` and workers with `dask worker {address}`"
        ) from exc


def check_dask(address: str | None, timeout: float | None = None) -> dict:
    """Connect once to the scheduler before any work; returns ``{"workers": n, "threads": t}``."""
    client = connect(address, timeout)
    try:
        threads = client.ncores()
        return {"workers": len(threads), "threads": int(sum(threads.values()))}
    finally:
        client.close()


@contextlib.contextmanager
def fe_parallel(fe_backend: str, n_jobs: int, dask_address: str | None = None) -> Iterator[Parallel]:
    """A joblib ``Parallel`` yielding results as they complete, on the chosen backend."""
    if fe_backend == "loky":
        yield Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
    elif fe_backend == "dask":
        client = connect(dask_address)
        try:
            with parallel_config(backend="dask", client=client):
                yield Parallel(return_as="generator_unordered")
        finally:
            client.close()
    else:
        raise FEBackendError(f"unknown fe_backend {fe_backend!r}; choose one of {', '.join(FE_BACKENDS)}")


def run_unordered(calls: dict[int, tuple], key: Callable[[Any], int], *, fe_backend: str = "loky",
                  n_jobs: int = 2, dask_address: str | None = None, label: str = "FE runs",
                  logger=None, retries: int = WORKER_LOSS_RETRIES) -> Iterator[Any]:
    """Run ``calls`` (``{key: joblib.delayed(f)(...)}``) and yield each result as it completes.

    ``key(result)`` must give back the call's key. A call counts as done once
    its result is yielded (the caller stores it before asking for the next).
    When a worker is lost (:func:`worker_lost_errors`), the calls not yet done
    are submitted again, up to ``retries`` times; then the last error is raised
    inside a :class:`FEBackendError` that says how many are missing.
    """
    pending = dict(calls)
    lost = 0
    while pending:
        try:
            with fe_parallel(fe_backend, n_jobs, dask_address) as parallel:
                for result in parallel(list(pending.values())):
                    pending.pop(key(result), None)
                    yield result
            if pending:  # a backend that returned fewer results than calls, without an error
                raise FEBackendError(f"{label}: the {fe_backend} backend returned no result for "
                                     f"{sorted(pending)}")
        except worker_lost_errors() as exc:
            lost += 1
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            why = f"{type(exc).__name__}: {first}"
            if lost > retries:
                raise FEBackendError(
                    f"{label}: workers were lost {lost} times, {len(pending)} runs still missing "
                    f"(results written so far are kept; run again to resume); last error {why}"
                ) from exc
            if logger is not None:
                logger.warning("%s: a %s worker was lost (%s); submitting the %d runs without a result again "
                               "(retry %d of %d)", label, fe_backend, why, len(pending), lost, retries)
