"""tasks.fe_runs.run_cores and the closure's on_the_cores: a run's ``n_jobs`` as PARDISO threads in this process."""

from __future__ import annotations

import types

import pytest

from fe_core.threads import _cores
from tasks.fe_runs import run_cores


@pytest.mark.parametrize("n_jobs, cores", [(1, 1), (2, 2), (-1, _cores())])
def test_run_cores_reads_n_jobs_from_settings_objects_and_the_closures_dict(n_jobs, cores):
    """--n-jobs 1 means one core, -1 every core this process may use, from the flow's settings or the closure's."""
    assert run_cores(types.SimpleNamespace(n_jobs=n_jobs)) == cores
    assert run_cores({"n_jobs": n_jobs}) == cores


def test_a_closure_step_runs_with_pardiso_on_the_runs_cores(monkeypatch):
    from contextlib import contextmanager

    from fe_core.solvers import pardiso
    from tasks.closure.steps import on_the_cores

    seen = []

    @contextmanager
    def threads(n):
        seen.append(n)
        yield

    monkeypatch.setattr(pardiso, "threads", threads)

    @on_the_cores
    def step(root, problem, settings, extra):
        return root, extra

    assert step("r", None, {"n_jobs": 1}, extra=5) == ("r", 5)
    assert step("r", None, {"n_jobs": 2}, 7) == ("r", 7)
    assert seen == [1, 2]
