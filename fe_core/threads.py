"""Independent pieces of the main process's work on every core: a thread pool, results in order.

The closure's exact search (:mod:`fe_core.closure.far.search`) runs in the flow's main process while the FE
workers wait: its joint fits of the reduced model, its restarts and its scan of the places one by one are
independent of each other, and their products (small eigenproblems, matrix products) run mostly outside Python's
lock, so two threads take 0.71 of one's wall time on them (8 joint fits on the held-out panel hb06, measured:
2.99 -> 2.12 s). Each piece is the same computation as in one thread: the results do not depend on the threads.

:data:`THREADS` (default: the cores this process may use, at most 4) is read at each call; 1 runs in the caller.
Worker processes that already fill the cores between them (the closure's FE checks, one per core) run their pieces
in their own thread under :func:`at_most` ``(1)``. :func:`cores` turns a run's ``n_jobs`` into a number of cores.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

__all__ = ["THREADS", "at_most", "cores", "thread_map"]

T = TypeVar("T")
R = TypeVar("R")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


#: Threads of :func:`thread_map` (the environment's ``FE_THREADS`` if set).
THREADS = int(os.environ.get("FE_THREADS", min(4, _cores())))


def cores(n_jobs) -> int:
    """The cores a run's ``n_jobs`` stands for: -1 (any negative) every core this process may use, else
    ``n_jobs`` (at least 1; None or 0 count as 1)."""
    n = int(n_jobs or 1)
    return _cores() if n < 0 else max(n, 1)


@contextmanager
def at_most(n: int) -> Iterator[None]:
    """Within the block :func:`thread_map` uses at most ``n`` threads (in this process; restored after)."""
    global THREADS
    before = THREADS
    THREADS = max(1, min(int(n), before))
    try:
        yield
    finally:
        THREADS = before


def thread_map(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` on ``threads`` threads (default :data:`THREADS`), in the items' order; in the
    caller's thread when there is one item or one thread. An exception in ``fn`` is raised here."""
    items = list(items)
    n = THREADS if threads is None else int(threads)
    if n < 2 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(n, len(items))) as pool:
        return list(pool.map(fn, items))
