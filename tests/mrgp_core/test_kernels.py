"""Squared-exponential correlations (Eq. 8): conventions, ARD, derivatives."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.gaussian_process.kernels import RBF

from mrgp_core import kernels

EXACT = 1e-13  # same arithmetic, different route
FD_STEP = 1e-6
FD_RTOL = 1e-7


def test_isotropic_kernel_divides_squared_distance_by_2l_like_sklearn_rbf_of_sqrt_l(make_rng):
    rng = make_rng()
    A, B = rng.uniform(-1, 1, (7, 3)), rng.uniform(-1, 1, (5, 3))
    l = 0.37
    by_hand = np.exp(-np.sum((A[:, None] - B[None]) ** 2, axis=-1) / (2 * l))
    np.testing.assert_allclose(kernels.correlation(A, B, np.array([l])), by_hand, rtol=EXACT)
    np.testing.assert_allclose(kernels.correlation(A, B, np.array([l])), RBF(np.sqrt(l))(A, B), rtol=EXACT)


def test_ard_matches_sklearn_anisotropic_rbf_and_reduces_to_isotropic(make_rng):
    rng = make_rng()
    A, B = rng.uniform(-1, 1, (6, 3)), rng.uniform(-1, 1, (4, 3))
    ls = np.array([0.2, 1.5, 0.04])
    np.testing.assert_allclose(kernels.correlation(A, B, ls), RBF(np.sqrt(ls))(A, B), rtol=EXACT)
    diffs = kernels.squared_differences(A, B)
    np.testing.assert_allclose(kernels.correlation_from_squared(diffs, ls), RBF(np.sqrt(ls))(A, B), rtol=EXACT)
    same = np.full(3, 0.3)
    np.testing.assert_allclose(
        kernels.correlation_from_squared(diffs, same),
        kernels.correlation_from_squared(kernels.squared_distances(A, B), same[:1]),
        rtol=EXACT,
    )


def test_squared_differences_sum_to_squared_distances(make_rng):
    A = make_rng().uniform(-2, 2, (8, 4))
    np.testing.assert_allclose(kernels.squared_differences(A).sum(axis=0), kernels.squared_distances(A), atol=EXACT)
    assert np.all(np.diag(kernels.squared_distances(A)) == 0.0)


@pytest.mark.parametrize("ls", [np.array([0.3]), np.array([0.3, 2.0, 0.05])])
def test_derivative_wrt_log_length_scale_matches_finite_differences(make_rng, ls):
    A = make_rng().uniform(-1, 1, (6, 3))
    sq = kernels.squared_distances(A) if ls.size == 1 else kernels.squared_differences(A)
    R = kernels.correlation_from_squared(sq, ls)
    dR = kernels.correlation_grad_log_length_scale(R, sq, ls)
    assert dR.shape == (ls.size, 6, 6)
    for j in range(ls.size):
        step = np.zeros(ls.size)
        step[j] = FD_STEP
        fd = (kernels.correlation_from_squared(sq, ls * np.exp(step))
              - kernels.correlation_from_squared(sq, ls * np.exp(-step))) / (2 * FD_STEP)
        np.testing.assert_allclose(dR[j], fd, rtol=FD_RTOL, atol=FD_RTOL)


def test_check_length_scale_rejects_wrong_shapes_and_values():
    assert kernels.check_length_scale(0.5, "iso", 4).shape == (1,)
    with pytest.raises(ValueError, match="needs 4"):
        kernels.check_length_scale([0.5, 1.0], "ard", 4)
    with pytest.raises(ValueError, match="positive"):
        kernels.check_length_scale(0.0, "iso", 2)
    with pytest.raises(ValueError, match="valid kernels are iso, ard"):
        kernels.check_length_scale(1.0, "matern", 2)
