"""Test hook: kill the process at a named point, to prove that a run survives it.

Set ``MRGP_KILL_AT`` to a pattern (``fnmatch`` syntax) of a point name,
optionally followed by ``@N`` to kill at the N-th matching point reached by
this process (default the first). At that point the process sends itself
SIGKILL: no ``finally`` blocks, no flushing, exactly like ``kill -9`` or a
power cut of the process. Unset (the normal case), :func:`kill_point` costs
one dictionary look-up.

Point names (``<run>`` is the run folder's absolute path)::

    before-rename:<run>/iteration=K/stage=S/NAME   a file is fully written under its temporary
                                                    name and not yet renamed into place (also
                                                    manifest.json, summary.json, _stage.json)
    tables-written/iteration=K/stage=S             a stage's tables are written, its record is not
    stage-finished/iteration=K/stage=S             a stage's record is written (between stages)
    fe-result-written/iteration=K/sample=ID        an FE result is on disk, its log line is not
    fe-logged/iteration=K/sample=ID                an FE result and its log line are written
    local-fd-run/iteration=K/sample=ID/run=I       one of the m + 1 solver runs of a black-box model's
                                                    forward-difference Jacobian is done (its solver folder is
                                                    complete), the request's result is not written yet

Examples: ``MRGP_KILL_AT='stage-finished/iteration=2/stage=train'``,
``MRGP_KILL_AT='before-rename:*/stage=fe/sample=*.parquet@3'``.
This is only for fault-injection tests (``tests/flows/test_kill_anywhere.py``).
"""

from __future__ import annotations

import fnmatch
import os
import signal

__all__ = ["KILL_ENV", "kill_point"]

KILL_ENV = "MRGP_KILL_AT"
_hits: dict[str, int] = {}


def kill_point(name: str) -> None:
    """SIGKILL this process if ``MRGP_KILL_AT`` selects the point ``name``."""
    spec = os.environ.get(KILL_ENV)
    if not spec:
        return
    pattern, _, count = spec.rpartition("@") if "@" in spec else (spec, "", "1")
    if fnmatch.fnmatchcase(name, pattern):
        _hits[spec] = _hits.get(spec, 0) + 1
        if _hits[spec] == int(count):
            os.kill(os.getpid(), signal.SIGKILL)
