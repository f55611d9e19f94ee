"""The hybrid stops at a local fit whose misfit is the model's own error (issue 40: the clean held-out he08, he13,
he17 spent 53-132 FE runs on basins that could not exist, for a misfit smaller than one mode half a per cent off).

The data are the three-plate model's own FRFs with its stiffness distribution a little off (twelve small patches of
cells, each softened or stiffened by up to 30 %; the largest frequency shift 0.4 %), at 0.1 % noise: the closure's
test of the same data (``tests/fe_core/test_mode_shifts.py``) calls what is left the model's own error. The same
model with a 0.15 kg point mass instead leaves four times that: the run goes on to the screens.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from fe_core.closure.effects import Applied, PointMass, build_library, extended_frf
from fe_core.inference.frf_data import FRFData
from fe_core.solvers.sensitivity import frf_jacobian
from strategies.base import run_loop
from strategies.hybrid import Hybrid, HybridOptions

FREQS = np.arange(20.0, 600.0, 1.0)
OPTIONS = HybridOptions(noise=0.001, max_cost=40.0)


def _data(model, applied, seed=5):
    u = np.abs(extended_frf(model, ALPHA_ACTUAL, FREQS, applied))
    return FRFData.grid(FREQS, u * np.exp(0.001 * np.random.default_rng(seed).standard_normal(u.shape)))


def _patches(model):
    patch = {e.kind: e for e in build_library(model, ["patch"])}["patch"]
    small = [loc for loc in patch.locations() if loc.endswith("r1")]
    rng = np.random.default_rng(11)
    return [Applied(patch, small[i], np.array([v]))
            for i, v in zip(rng.choice(len(small), 12, replace=False), rng.uniform(-0.3, 0.3, 12))]


def _run(model, data, options=OPTIONS):
    def evaluate(batch):
        out = []
        for x, jacobian in zip(batch.points, batch.jacobian):
            if jacobian:
                Z, dZ = frf_jacobian(model, x, FREQS)
                out.append((Z.ravel(), dZ.reshape(Z.size, -1)))
            else:
                out.append((model.parameter_frf(x, FREQS).ravel(), None))
        return out

    m = model.n_segments
    strategy = Hybrid(np.zeros(m), data, np.full(m, -0.9), np.full(m, 0.5), options,
                      screen_model=lambda: (model, ""))
    run_loop(strategy, evaluate)
    return strategy


@pytest.mark.slow
def test_a_local_fit_within_the_models_own_error_ends_the_run_converged_without_screens(benchmark_model):
    strategy = _run(benchmark_model, _data(benchmark_model, _patches(benchmark_model)))
    report = strategy.report()
    own = strategy.evidence["own_error"]
    assert not strategy.check_infos[0]["at_floor"]            # the check alone calls it structure ...
    assert own["within"] and own["before"] <= own["single"]   # ... the size of one mode half a per cent off
    assert strategy.status == "own error" and report.converged and strategy.cycle == 0
    assert strategy.evidence["screens"] == []                 # no screen, no global cycle: the local phase's runs
    assert report.candidates == [strategy.check_infos[0]["sample_id"]]
    assert "own error" in report.stop_reason and report.fields["own_error"] == own
    best = strategy.runs[report.candidates[0]][1]
    assert np.max(np.abs(best - ALPHA_ACTUAL)) < 0.05          # the factors found all the same


@pytest.mark.slow
def test_a_point_mass_beyond_the_models_own_error_is_screened_and_not_converged(benchmark_model):
    mass = [Applied(PointMass(benchmark_model), "node 201", np.array([0.15]))]
    strategy = _run(benchmark_model, _data(benchmark_model, mass))
    own = strategy.evidence["own_error"]
    assert not own["within"] and own["before"] > 3 * own["single"]
    assert strategy.evidence["screens"] and strategy.status != "own error"
    assert not strategy.report().converged
