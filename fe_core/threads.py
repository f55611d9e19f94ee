"""Independent pieces of the main process's work on every core: a thread pool, results in order.

The closure's exact search (:mod:`fe_core.closure.far.search`) runs in the flow's main process while the FE
workers wait: its joint fits of the reduced model, its restarts and its scan of the places one by one are
independent of each other, and their products (small eigenproblems, matrix products) run mostly outside Python's
lock, so two threads take 0.71 of one's wall time on them (8 joint fits on the held-out panel hb06, measured:
2.99 -> 2.12 s). Each piece is the same computation as in one thread: the results do not depend on the threads.

:data:`THREADS` (default: the cores this process may use, at most 4) is read at each call; 1 runs in the caller.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

__all__ = ["THREADS", "thread_map"]

T = TypeVar("T")
R = TypeVar("R")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


#: Threads of :func:`thread_map` (the environment's ``FE_THREADS`` if set).
THREADS = int(os.environ.get("FE_THREADS", min(4, _cores())))


def thread_map(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` on ``threads`` threads (default :data:`THREADS`), in the items' order; in the
    caller's thread when there is one item or one thread. An exception in ``fn`` is raised here."""
    items = list(items)
    n = THREADS if threads is None else int(threads)
    if n < 2 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(min(n, len(items))) as pool:
        return list(pool.map(fn, items))
