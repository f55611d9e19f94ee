"""The emulator's Gauss-Newton: its batched forward-difference Jacobian is scipy's, and its end points are."""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative  # what least_squares(diff_step=...) calls; not public

from strategies.emulation import forward_difference_jacobian, refine_on_emulator


def _residuals(X):
    """A smooth nonlinear residual of 3 inputs, 5 outputs, for a batch of points (k, 3)."""
    X = np.atleast_2d(X)
    a, b, c = X.T
    return np.column_stack([a - 0.3, np.sin(3 * b) + a * c, np.exp(c) - 1.2, a * b - 0.1, 2 * c - b ** 2])


@pytest.mark.parametrize("x", [[0.2, -0.4, 0.5], [0.0, 0.7, -1.0], [1.0, -1.0, 0.9999999], [-1.0, 1.0, 0.0]])
def test_the_batched_jacobian_is_scipys_forward_difference_at_the_bounds_and_inside(x):
    low, high = -np.ones(3), np.ones(3)
    x = np.array(x)
    expected = approx_derivative(lambda v: _residuals(v)[0], x, method="2-point", rel_step=1e-6,
                                 bounds=(low, high))
    # the same steps and the same differences: equal up to the last bits of the function's values
    np.testing.assert_allclose(forward_difference_jacobian(_residuals, x, low, high), expected, rtol=1e-12,
                               atol=1e-12)


def test_the_refined_points_are_those_of_scipys_own_differences():
    low, high = -np.ones(3), np.ones(3)
    starts = np.array([[0.9, 0.9, 0.9], [-0.5, 0.2, -0.8]])
    ours = refine_on_emulator(_residuals, starts, low, high, tolerance=1e-12)
    for x0, x in zip(starts, ours):
        theirs = least_squares(lambda v: _residuals(v)[0], x0, bounds=(low, high), method="trf", diff_step=1e-6,
                               ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=50).x
        np.testing.assert_allclose(x, theirs, atol=1e-7)
