"""The memory this machine offers a run, before it starts and while it runs (issue 41).

:func:`available_bytes` is what the preflight weighs a model's estimate against (:func:`flows.preflight.check_memory`);
:func:`runs_that_fit` is asked again before each round of several FE runs of a large model goes to worker
processes (:class:`tasks.fe_runs.FEStage`): by then the flow's process holds the model, the data and what the
strategy's steps made (the effect screens' reduced models, say), which the estimate before the run cannot see, so
the round takes as many workers as the memory left holds, and one FE run at a time in this process when not two
(a worker killed by the kernel for memory loses the round; a machine that swaps loses the hour).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["MEMORY_ENV", "available_bytes", "runs_that_fit"]

#: Environment variable: the memory this machine offers the run, MB (default: what the OS reports available,
#: within a cgroup's limit); for a container, or to keep room for other work.
MEMORY_ENV = "MRGP_MEMORY_AVAILABLE_MB"


def available_bytes(used_by_run: bool = False) -> float:
    """The memory the run may use: :data:`MEMORY_ENV` when set, else the OS's available memory, within the
    cgroup's limit (a container). ``used_by_run``: what is left of it now, while the run is under way (the
    environment's amount less this process's resident memory; the OS's figure has it taken already)."""
    env = os.environ.get(MEMORY_ENV)
    if env:
        return float(env) * 1e6 - (_resident() if used_by_run else 0.0)
    avail = _meminfo_available()
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = float(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        if limit != "max":
            avail = min(avail, float(limit) - used)
    except (OSError, ValueError):
        pass
    return avail


def runs_that_fit(wanted: int, per_run: float | None, available: float | None = None) -> int:
    """How many of ``wanted`` FE runs at once fit in ``available`` bytes (default: :func:`available_bytes` left
    now), each needing ``per_run`` (None: unknown, all ``wanted``); at least 1."""
    if per_run is None or per_run <= 0 or wanted <= 1:
        return max(1, int(wanted))
    left = available_bytes(used_by_run=True) if available is None else float(available)
    return max(1, min(int(wanted), int(left // per_run)))


def _resident() -> float:
    """This process's resident memory, bytes (0 where ``/proc`` has none)."""
    return _proc_kib("/proc/self/status", "VmRSS:") or 0.0


def _meminfo_available() -> float:
    """``MemAvailable`` of ``/proc/meminfo`` (Linux), bytes; elsewhere the free physical pages."""
    found = _proc_kib("/proc/meminfo", "MemAvailable:")
    return found if found is not None else float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def _proc_kib(path: str, key: str) -> float | None:
    """The ``key`` line of a ``/proc`` file given in kB, in bytes; None when the file or the line is missing."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key):
                return float(line.split()[1]) * 1024
    except OSError:
        pass
    return None
