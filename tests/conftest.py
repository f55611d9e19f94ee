"""Shared fixtures: seeded generators and the (cached) benchmark model."""

from __future__ import annotations

import json
import os

# One BLAS thread, as the flow uses: OpenBLAS's threads make the small dense algebra of
# the MRGP and the closure several times slower on 2 cores. The variables reach the
# subprocesses the tests start; threadpoolctl limits this process, whose numpy may
# already be loaded by a plugin.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(1)

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
