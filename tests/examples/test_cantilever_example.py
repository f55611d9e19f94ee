"""Example (b) with an undeclared effect: the closure finds the point mass scikit-fem's measurement carries.

``data/examples/cantilever_matrices/measured_point_mass.csv`` is scikit-fem's own FRF (its matrices, its
condensation, scipy's direct solve; ``python -m benchmarks.make.matrix_example``) of the cantilever with a
0.6 kg point mass at node 208 that ``model.toml`` does not declare, 0.5 % noise. The README shows the same
through ``python -m flows.update ... --close-loop``; here the closure's core runs from the nominal model
(alpha = 0, as ``benchmarks.closure`` does), without an MRGP run first.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fe_core.closure.loop import close_loop
from fe_core.io import read_model
from fe_core.inference.residual import overall_error
from flows.config import REPO
from tasks.io.measured import read_measured

EXAMPLE = REPO / "data" / "examples" / "cantilever_matrices"


def test_the_closure_finds_the_undeclared_point_mass_and_the_stiffness_factors():
    truth = json.loads((EXAMPLE / "truth.json").read_text())["point_mass"]
    model = read_model(EXAMPLE / "model.toml")
    measured = read_measured(EXAMPLE / truth["file"])
    u = measured.amplitude
    result = close_loop(model, measured.frequencies_hz, u, np.zeros(model.n_segments), noise=truth["noise"],
                        restarts=2, alpha_bounds=(-0.5, 0.5))
    assert result.verdict == "explained" and [c.effect for c in result.steps] == ["point_mass"]
    added = result.steps[0]
    assert added.location == f"node {truth['node']}"
    # 0.5 % noise on 75 amplitudes: the mass to about 1 %, the factors to a few thousandths
    assert added.fit.values[0] == pytest.approx(truth["mass_kg"], rel=0.02)
    alpha = np.asarray(truth["alpha"])
    assert np.max(np.abs(result.final.alpha - alpha)) < 0.005
    assert np.max(np.abs(result.baseline.alpha - alpha)) > 0.03  # alpha alone had absorbed the mass
    assert overall_error(result.final.relative(u)) < 1.1 * result.before.noise_floor
    assert overall_error(result.baseline.relative(u)) > 5 * result.before.noise_floor
