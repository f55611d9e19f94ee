"""Fixtures for flow tests: a reduced configuration that runs in seconds."""

from __future__ import annotations

import pytest

from flows.config import UpdateConfig

REDUCED = dict(q=8, w=400, s=4, z=6, max_iterations=3, max_fe_evaluations=16, threshold=1e-6, n_jobs=1,
               trainer="gradient", seed=11)


@pytest.fixture
def reduced_config(tmp_path) -> UpdateConfig:
    return UpdateConfig(run_id="reduced", runs_dir=str(tmp_path / "runs"), **REDUCED)


@pytest.fixture
def reduced_settings() -> dict:
    return dict(REDUCED)
