"""The Laplace intervals of a tall Jacobian need memory of the Jacobian's size, not N x N.

A run on 1,601 lines x 6 channels has N = 9,606 log-amplitude values; the full SVD of J built U, N x N
(0.74 GB; 2.9 GB with complex residuals), the peak memory of the whole update (1.67 GB measured with
``/usr/bin/time -v``, 0.46 GB with the thin SVD, the same summary bit for bit). Here N = 6,000
(a full U would be 288 MB) and the covariance is checked against ``sigma^2 (J^T J)^-1``.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from fe_core.inference.laplace import laplace_intervals


def test_tall_jacobian_stays_small_and_gives_the_normal_equations_covariance():
    rng = np.random.default_rng(30)
    N, m = 6000, 6
    J = rng.standard_normal((N, m)) * np.array([1.0, 3.0, 0.3, 2.0, 1.0, 0.5])
    r = 0.01 * rng.standard_normal(N)
    tracemalloc.start()
    iv = laplace_intervals(r, J, np.zeros(m), noise=0.01)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.0f} MB"  # J is 0.29 MB; a full U would be 288 MB
    np.testing.assert_allclose(iv.covariance, 0.01**2 * np.linalg.inv(J.T @ J), rtol=1e-10)


def test_fewer_values_than_parameters_keep_the_null_directions():
    J = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])  # N = 2 < m = 3: alpha_3 unseen
    iv = laplace_intervals(np.array([0.01, -0.01]), J, np.zeros(3), noise=0.01)
    assert np.isinf(iv.std[2]) and np.allclose(iv.std[:2], [0.01, 0.005])
