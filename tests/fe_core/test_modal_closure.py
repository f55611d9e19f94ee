"""The closure on modal residuals (fe_core/modal_update/closure.py).

Data: the benchmark's 6 modes at the 18 test nodes of data/examples/modal, made by the SPEC's model
(:func:`fe_core.benchmark.three_plate`) at the actual alpha WITH a point mass of 0.15 kg (2.6 % of the
structure) at a node the fitted model does not have, 0.2 % frequency and 2 % shape noise (seeded). The fitted
model is the example's model file without the mass. The closure after the modal update must name a point mass
near the true node. The effect's eigenvalue derivative is checked against finite differences of the
eigenvalues. (Clean data giving no effect: tests/flows/test_modal_resume.py, through the flow.)
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.make.modal_point_mass import MASS_KG, modes_with_mass
from fe_core.closure.effects import PointMass
from fe_core.modal_update import ModalResidual, fit_modes
from fe_core.modal_update.closure import modal_closure
from fe_core.modal_update.nelson import eigen_derivatives, eigen_derivatives_at
from fe_core.solvers.modal import eigenmodes
from flows.problem import load_model
from tasks.modal_data import match_modes

MODEL = "data/examples/modal/model.toml"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)[0]


def test_the_effect_jacobian_of_eigenvalues_matches_finite_differences(model):
    lib = PointMass(model)
    loc = lib.locations()[len(lib.locations()) // 2]
    dM = lib.terms(np.zeros(6), loc, np.array([1.0])).mass
    K, M = model.stiffness(np.zeros(6)), model.mass()
    freqs, vecs = eigenmodes(K, M, 6)
    lam = (2 * np.pi * freqs) ** 2
    dlam, dpsi = eigen_derivatives_at(K, M, lam, vecs, [(None, dM)], model.outputs, range(6))
    _, dphi = eigen_derivatives(K, M, lam, vecs, [(None, dM)])  # Nelson's full solve: the adjoint's reference
    assert np.allclose(dpsi, np.einsum("nt,mnp->mtp", model.outputs.toarray(), dphi), rtol=0,
                       atol=1e-8 * np.abs(dpsi).max())
    h = 1e-3  # kg: the second-order term is ~h * |d2 lambda| << h * |d lambda|
    f2, _ = eigenmodes(K, M + h * dM, 6)
    fd = ((2 * np.pi * f2) ** 2 - lam) / h
    assert np.allclose(dlam[:, 0], fd, rtol=2e-3, atol=1e-6 * lam.max())
    assert np.all(dlam[:, 0] <= 0)  # a mass lowers every frequency (Rayleigh)


def test_a_point_mass_missing_from_the_model_is_named_near_its_node(model):
    where, modes = modes_with_mass()  # benchmarks/make/modal_point_mass.py
    data = match_modes(modes, model)
    residual = ModalResidual(model, data.outputs, modes.frequencies_hz, modes.shapes, 0.002, 0.02, 12, 0.6)
    lower, upper = np.full(6, -0.95), np.full(6, 1.0)
    residual.set_active(np.zeros(6))
    fit = fit_modes(residual, lower, upper, n_starts=1)
    out = modal_closure(residual, fit.theta, lower, upper, stated=True)
    assert out["before"]["structured"], out["before"]  # the mass shows in what the update left
    chosen = out["chosen"]
    assert chosen is not None and chosen["effect"] == "point_mass", out["candidates"][:3]
    # the data are the model with the mass and noise: once the mass is in, what is left is noise
    assert out["verdict"] == "explained" and not out["after"]["structured"], out["after"]
    distance = np.linalg.norm(np.asarray(chosen["position_m"]) - where)
    assert distance < 0.015, (chosen["location"], chosen["position_m"], where)  # within one element (14.4 mm)
    assert abs(chosen["value"] - MASS_KG) < 3 * chosen["sd"] + 0.02 * MASS_KG, (chosen["value"], chosen["sd"])
    assert chosen["chi2"] < 0.2 * out["before"]["chi2"]
