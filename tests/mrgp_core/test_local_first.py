"""local_first on analytic residuals (independent of the FE model): local when it suffices, global when not."""

import numpy as np
import pytest

pytest.importorskip("dfols")

from mrgp_core.strategies import local_first  # noqa: E402
from mrgp_core.strategies.local_first import at_noise_floor  # noqa: E402

W = np.linspace(4.0, 9.0, 40)  # plays the role of the frequencies (one "sensor")
TRUTH = np.array([-0.75, 0.3])


def _residual(x, noise=None):
    r = np.sin(W * x[0]) - np.sin(W * TRUTH[0]) + 0.3 * (x[1] - TRUTH[1])
    return r if noise is None else r + noise


def test_goes_global_from_a_wrong_basin_and_finds_the_truth():
    # DFO-LS alone from 0 stalls at x0 ~ 0.037 with mean |r| ~ 0.39 on this problem.
    res = local_first(lambda pts: [_residual(x) for x in pts], np.zeros(2), -np.ones(2), np.ones(2), W)
    assert res.status == "target"
    assert len(res.minima) >= 2 and res.minima[0][1] > 0.1  # first local phase stalled above the noise
    assert np.max(np.abs(res.x - TRUTH)) < 1e-3
    assert res.rounds < res.evaluations  # the space-filling batch is one round


def test_stays_local_when_the_start_is_in_the_basin():
    res = local_first(lambda pts: [_residual(x) for x in pts], np.array([-0.6, 0.0]), -np.ones(2), np.ones(2), W)
    assert res.status == "target" and len(res.minima) == 1
    assert res.rounds == res.evaluations  # no global batch was needed


def test_noisy_data_stop_at_the_floor():
    noise = 0.01 * np.random.default_rng(3).standard_normal(W.size)
    res = local_first(lambda pts: [_residual(x, noise) for x in pts], np.array([-0.6, 0.0]), -np.ones(2),
                      np.ones(2), W)
    assert res.status == "floor" and len(res.minima) == 1
    assert np.max(np.abs(res.x - TRUTH)) < 0.05


def test_noise_floor_decision():
    rng = np.random.default_rng(0)
    assert at_noise_floor(0.01 * rng.standard_normal(W.size), W, 1e-4, 1.5)
    assert not at_noise_floor(0.05 * np.sin(W), W, 1e-4, 1.5)  # smooth misfit: structure
