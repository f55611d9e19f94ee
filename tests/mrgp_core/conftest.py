"""Fixtures for the MRGP tests: seeded generators and small synthetic data sets.

The generators have their own names (``make_rng``) rather than overriding the
top-level ``rng`` fixture, which other tests in this directory use.

BLAS is limited to one thread while these tests run: the matrices are small
(r <= 60), and on a two-core machine OpenBLAS threads make each call an order
of magnitude slower (the stochastic trainers evaluate the likelihood
thousands of times). This changes speed only, never results beyond rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

SEED = 31_4159


@pytest.fixture(autouse=True)
def _single_blas_thread():
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # threadpoolctl comes with scikit-learn; without it, just run slower
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture
def make_rng():
    """Factory of seeded generators: ``make_rng(i)`` is reproducible and distinct for each ``i``."""
    return lambda offset=0: np.random.default_rng(SEED + offset)


def correlated_responses(X: np.ndarray, k: int, rng: np.random.Generator, decades: float = 4.0) -> np.ndarray:
    """``k`` smooth, correlated responses of ``X`` with scales spread over ``decades``.

    Mixtures of three smooth latent functions, a linear trend and a small
    smooth component of each column's own (so the responses are correlated
    but not exactly of low rank), each column scaled by ``10**u`` with ``u``
    uniform over ``decades``.

    Returns
    -------
    ndarray, shape (r, k)
    """
    d = X.shape[1]
    W = rng.normal(size=(3, d))
    latent = np.column_stack([np.sin(X @ W[0]), np.cos(1.5 * X @ W[1]), np.exp(-0.5 * (X @ W[2]) ** 2)])
    mix = rng.normal(size=(3, k))
    trend = X @ rng.normal(scale=0.3, size=(d, k))
    own = 0.1 * np.sin(X @ rng.normal(size=(d, k)) + rng.uniform(0, 2 * np.pi, k))
    scales = 10.0 ** rng.uniform(-decades / 2, decades / 2, k)
    return (latent @ mix + trend + own) * scales


@pytest.fixture
def small_problem(make_rng):
    """r = 14 runs, d = 2 inputs, k = 3 responses (full-rank Q-hat for every mean)."""
    rng = make_rng(1)
    X = rng.uniform(-1, 1, (14, 2))
    return X, correlated_responses(X, 3, rng)


@pytest.fixture
def wide_problem(make_rng):
    """r = 9 runs, d = 2 inputs, k = 12 responses: Q-hat is singular (rank <= r - q < k)."""
    rng = make_rng(2)
    X = rng.uniform(-1, 1, (9, 2))
    return X, correlated_responses(X, 12, rng)


@pytest.fixture
def first_iteration(make_rng):
    """The paper's first iteration: r = 20 uniform runs in [-1, 1]^6, k = 72 responses over four decades."""
    rng = make_rng(3)
    X = rng.uniform(-1, 1, (20, 6))
    X_new = rng.uniform(-1, 1, (500, 6))
    return X, correlated_responses(X, 72, rng), X_new
