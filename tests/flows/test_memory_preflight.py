"""A model too big for the machine says so before any work (issue 41): exit 2 naming the model and the
estimate, with the hint of ``--n-jobs 1``; the estimate's factor against the one PARDISO makes.

The machine's memory is faked through ``MRGP_MEMORY_AVAILABLE_MB`` (flows.memory.MEMORY_ENV) around the
estimate of the bracket's coarse model (8,388 DOFs), so the same small model is refused, refused with the hint,
or let through. The accuracy reference is PARDISO's own analysis of the assembled K.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flows import memory, preflight, update
from flows import problem as problems
from flows.config import REPO, ConfigError, load_config

MODEL = "data/examples/bracket/model_coarse.toml"
MEASURED = "data/examples/bracket/measured.csv"


@pytest.fixture(scope="module")
def footprint():
    """The estimate with two FE runs at once (the default ``n_jobs``), and with one."""
    two = memory.estimate(REPO / MODEL, 2)
    return two, two.with_jobs(1)


def _config(tmp_path, **kw):
    return load_config(None, model=MODEL, measured=MEASURED, runs_dir=str(tmp_path / "runs"), run_id="too-big",
                       **kw)


def test_too_big_is_refused_before_any_assembly(footprint, tmp_path, monkeypatch, capsys):
    two, one = footprint
    monkeypatch.setenv(memory.MEMORY_ENV, str(0.5 * one.total / 1e6))  # less than even one FE run at a time
    monkeypatch.setattr(problems, "load_model", lambda *a, **k: pytest.fail("the model was read before the check"))
    rc = update.main(["--model", MODEL, "--measured", MEASURED, "--runs-dir", str(tmp_path / "runs"),
                      "--run-id", "too-big"])
    err = capsys.readouterr().err
    assert rc == 2
    assert MODEL in err and "would not fit in memory" in err and f"{two.total / 1e9:.1f} GB" in err
    assert "coarser mesh or a machine with more memory" in err
    assert not (tmp_path / "runs" / "too-big").exists()


def test_hint_names_n_jobs_1_when_one_fe_run_at_a_time_fits(footprint, tmp_path, monkeypatch):
    two, one = footprint
    assert two.total > one.total  # two factorisations at once in a global round
    monkeypatch.setenv(memory.MEMORY_ENV, str(0.5 * (one.total + two.total) / 1e6))
    with pytest.raises(ConfigError, match=r"--n-jobs 1") as err:
        preflight.check_memory(_config(tmp_path, n_jobs=2))
    assert f"about {one.total / 1e9:.1f} GB" in str(err.value)
    assert preflight.check_memory(_config(tmp_path, n_jobs=1)).total == pytest.approx(one.total)


def test_enough_memory_passes(footprint, tmp_path, monkeypatch):
    two, _ = footprint
    monkeypatch.setenv(memory.MEMORY_ENV, str(2 * two.total / 1e6))
    assert preflight.check_memory(_config(tmp_path, n_jobs=2)).total == pytest.approx(two.total)


def test_factor_estimate_against_pardiso(footprint):
    """The node graph's symbolic factor against PARDISO's analysis of the assembled K (supports removed):
    an upper bound within 15 %."""
    from fe_core.io import read_model
    from fe_core.solvers import pardiso

    two, _ = footprint
    model = read_model(REPO / MODEL)
    K = model.stiffness(np.zeros(model.n_segments))
    pardiso.clear()
    solve = pardiso.cholesky(K)
    handle = next(h for pool in pardiso._POOL.values() for h in pool if h.pins)
    actual = handle.nnz_factor
    del solve
    assert actual <= two.nnz_L <= 1.15 * actual
    assert K.nnz <= two.nnz_K <= 1.1 * K.nnz
