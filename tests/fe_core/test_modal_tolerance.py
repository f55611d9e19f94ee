"""eigenmodes(tol=...): ARPACK's looser stopping rule (the large models' band check) keeps the frequencies to
far better than the check needs. Reference: the same Lanczos at machine precision (tol = 0), itself checked
against the benchmark's published frequencies in test_modal_update.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fe_core.io import read_model
from fe_core.solvers.modal import eigenmodes

MODEL = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket" / "model_coarse.toml"


def test_loose_tolerance_keeps_the_frequencies():
    model = read_model(MODEL)
    K, M = model.stiffness(np.zeros(model.n_segments)), model.mass(None)
    exact = eigenmodes(K, M, 6)[0]
    loose = eigenmodes(K, M, 6, tol=1e-3)[0]
    np.testing.assert_allclose(loose, exact, rtol=1e-3)
