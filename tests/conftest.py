"""Shared fixtures: seeded generators and the (cached) benchmark model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def benchmark_model():
    from fe_core.benchmark import three_plate

    return three_plate()


@pytest.fixture(scope="session")
def expected() -> dict:
    path = SHARED / "benchmark" / "expected.json"
    if not path.exists():
        pytest.fail(f"{path} is missing: the tests need shared/ beside the repository")
    return json.loads(path.read_text())
