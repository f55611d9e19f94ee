"""The trust-region loop's pure pieces (mrgp_core.adaptive): region update, local training set, inverse receptance."""

import numpy as np
import pytest

from mrgp_core import adaptive

LOWER, UPPER = -np.ones(3), np.ones(3)


def test_first_region_is_the_whole_box_around_the_best_sample():
    X = np.array([[0.5, 0.0, 0.0], [0.1, 0.2, 0.3], [-0.5, 0.5, 0.9]])
    tr = adaptive.update_trust_region(None, X, np.array([0.3, 0.1, 0.2]))
    assert np.array_equal(tr.centre, X[1]) and tr.length == 1.0 and tr.best == 0.1
    low, high = tr.box(LOWER, UPPER)
    assert np.allclose(low, [-0.9, -0.8, -0.7]) and np.allclose(high, [1.0, 1.0, 1.0])  # clipped to the box


def test_region_doubles_after_two_successes_and_halves_after_a_failure():
    X = np.zeros((1, 3))
    tr = adaptive.TrustRegion(np.zeros(3), 0.25, 0, 0, 1.0)
    tr = adaptive.update_trust_region(tr, X, np.array([0.5]))  # improved: one success
    assert (tr.length, tr.successes, tr.best) == (0.25, 1, 0.5)
    tr = adaptive.update_trust_region(tr, X, np.array([0.4]))  # second success: doubled, counter reset
    assert (tr.length, tr.successes) == (0.5, 0)
    tr = adaptive.update_trust_region(tr, X, np.array([0.4 * (1 - 1e-4)]))  # below the 1e-3 relative: a failure
    assert (tr.length, tr.failures) == (0.25, 0) and tr.best == 0.4 * (1 - 1e-4)  # halved; the best seen kept
    for _ in range(20):
        tr = adaptive.update_trust_region(tr, X, np.array([1.0]))
    assert tr.length == pytest.approx(2.0**-7)  # never below the smallest side


def test_local_training_set_keeps_the_region_or_the_nearest_minimum():
    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (50, 3))
    tr = adaptive.TrustRegion(np.zeros(3), 0.5)
    inside = adaptive.local_training_set(X, tr, LOWER, UPPER, minimum=3)
    dist = np.max(np.abs(X) / 2.0, axis=1)
    assert set(inside) == set(np.flatnonzero(dist <= 0.5))
    few = adaptive.local_training_set(X, adaptive.TrustRegion(np.zeros(3), 0.01), LOWER, UPPER, minimum=5)
    assert set(few) == set(np.argsort(dist)[:5])


def test_inverse_receptance_round_trip_and_linearity_in_stiffness():
    Z = np.array([1e-6 - 2e-6j, -3e-7 + 1e-7j])
    assert np.allclose(adaptive.receptance_from_inverse(adaptive.inverse_receptance(Z)), Z, rtol=1e-14)
    # One mode: 1/Z = k (1 + alpha) - w^2 m + j w c is linear in alpha; the emulated outputs are too.
    w = np.linspace(0.9, 1.1, 5)
    G = np.array([adaptive.inverse_receptance(1.0 / ((1.0 + a) - w**2 + 0.02j * w)) for a in (-0.2, 0.0, 0.3)])
    slope = (G[1] - G[0]) / 0.2
    assert np.allclose(G[2], G[1] + 0.3 * slope, rtol=1e-12, atol=1e-12)


def test_refine_on_emulator_finds_the_minimum_of_a_mean_inside_the_box():
    target = np.array([0.3, -0.2, 0.55])
    ends = adaptive.refine_on_emulator(lambda x: x - target, np.array([[0.0, 0.0, 0.0], [0.9, 0.9, 0.0]]),
                                       -np.full(3, 0.5), np.full(3, 0.5))
    assert np.allclose(ends, [0.3, -0.2, 0.5], atol=1e-6)  # the third coordinate stops at the region's edge
