"""A large model's FE run starts its Krylov space from the previous run's (fe_core.solvers.recycle): the
results are those of an unseeded space to the space's own tolerances, and a run at the same point needs one
block. Reference: the unseeded Krylov Jacobian (itself checked against the direct solve in
test_frf_derivatives.py). The bracket's coarse mesh stands in for a large model (the threshold lowered)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fe_core.io import read_model
from fe_core.solvers import recycle
from fe_core.solvers.sensitivity import frf_jacobian

MODEL = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket" / "model_coarse.toml"
FREQS = np.array([300.0, 320.0, 570.0, 1300.0, 2400.0, 3200.0])


@pytest.fixture(scope="module")
def model():
    return read_model(MODEL)


def fresh(model, theta):
    seed = model.__dict__.pop("_krylov_seed", None)
    try:
        return frf_jacobian(model, theta, FREQS, return_info=True)
    finally:
        if seed is not None:
            model.__dict__["_krylov_seed"] = seed


@pytest.mark.parametrize("step", [0.1, 1e-3])
def test_seeded_space_gives_the_unseeded_results(model, monkeypatch, step):
    monkeypatch.setattr(recycle, "MIN_DOFS", 0)
    monkeypatch.setattr(recycle, "MAX_STEP", 1.0)  # seeded at either step (the default seeds only small ones)
    recycle.forget(model)
    theta0 = np.array([-0.1, 0.15, 0.1, -0.15, 0.2, -0.1])
    frf_jacobian(model, theta0, FREQS)  # keeps its space
    assert model.__dict__.get("_krylov_seed") is not None
    theta1 = theta0 + step * np.array([1.0, -0.5, 0.3, 0.8, -1.0, 0.2])
    Z, dZ, info = frf_jacobian(model, theta1, FREQS, return_info=True)
    monkeypatch.setattr(recycle, "ENABLED", False)
    Z0, dZ0, info0 = fresh(model, theta1)
    size = np.abs(Z0).reshape(len(FREQS), -1).max(axis=1)  # each frequency's largest response
    assert np.max(np.abs(Z - Z0).reshape(len(FREQS), -1).max(axis=1) / size) < 1e-8
    scaled = np.abs(dZ - dZ0).reshape(len(FREQS), -1, dZ.shape[-1]).max(axis=1) / size[:, None]
    top = (np.abs(dZ0).reshape(len(FREQS), -1, dZ.shape[-1]).max(axis=1) / size[:, None]).max(axis=0)
    assert np.max(scaled.max(axis=0) / top) < 1e-7  # the derivative test's 1e-8, for two spaces
    assert info.converged and info0.converged


def test_same_point_again_needs_one_block(model, monkeypatch):
    monkeypatch.setattr(recycle, "MIN_DOFS", 0)
    recycle.forget(model)
    theta = np.full(6, 0.05)
    _, _, first = frf_jacobian(model, theta, FREQS, return_info=True)
    Z, dZ, again = frf_jacobian(model, theta, FREQS, return_info=True)
    width = model.n_sensors + 1
    assert again.solves == width < first.solves
    Z0, dZ0, _ = fresh(model, theta)
    assert np.max(np.abs(Z - Z0)) < 1e-8 * np.max(np.abs(Z0))


def test_a_space_seeds_only_a_run_within_max_step_of_it(model, monkeypatch):
    monkeypatch.setattr(recycle, "MIN_DOFS", 0)
    theta = np.full(6, 0.05)
    direction = np.array([1.0, -0.5, 0.3, 0.8, -1.0, 0.2])
    solves = {}
    for step in (0.0, 0.5 * recycle.MAX_STEP, 10 * recycle.MAX_STEP):
        recycle.forget(model)
        _, _, first = frf_jacobian(model, theta, FREQS, return_info=True)
        _, _, second = frf_jacobian(model, theta + step * direction, FREQS, return_info=True)
        solves[step] = (first.solves, second.solves)
    fresh_solves = solves[0.0][0]
    assert solves[0.0][1] < fresh_solves and solves[0.5 * recycle.MAX_STEP][1] < fresh_solves  # seeded
    assert solves[10 * recycle.MAX_STEP][1] >= 0.8 * fresh_solves  # a fresh space of its own
    assert "_krylov_point" in model.__dict__
    recycle.forget(model)
    assert "_krylov_point" not in model.__dict__ and "_krylov_seed" not in model.__dict__


def test_small_models_do_not_recycle(model):
    recycle.forget(model)
    assert recycle.MIN_DOFS > model.n_dofs
    frf_jacobian(model, np.zeros(6), FREQS)
    assert "_krylov_seed" not in model.__dict__


def test_a_column_major_space_gives_the_row_major_results(model, monkeypatch):
    """A large model's space is column-major and extends its reduced matrices one matrix at a time
    (BlockKrylov._extend_reduced); here forced on the coarse bracket, unseeded and then seeded, against the
    row-major space's results (the arithmetic of small models)."""
    from fe_core.solvers import block_krylov

    theta0 = np.array([-0.1, 0.15, 0.1, -0.15, 0.2, -0.1])
    theta1 = theta0 + 1e-3 * np.array([1.0, -0.5, 0.3, 0.8, -1.0, 0.2])
    monkeypatch.setattr(recycle, "MIN_DOFS", 0)
    results = {}
    for rows in (10**9, 0):  # row-major, then column-major
        monkeypatch.setattr(block_krylov, "COLUMN_MAJOR_ROWS", rows)
        recycle.forget(model)
        first = frf_jacobian(model, theta0, FREQS, return_info=True)
        second = frf_jacobian(model, theta1, FREQS, return_info=True)  # seeded by the first's space
        results[rows] = (first, second)
    for (Z, dZ, info), (Z0, dZ0, info0) in zip(results[0], results[10**9]):
        size = np.abs(Z0).reshape(len(FREQS), -1).max(axis=1)
        assert np.max(np.abs(Z - Z0).reshape(len(FREQS), -1).max(axis=1) / size) < 1e-8
        top = (np.abs(dZ0).reshape(len(FREQS), -1, dZ.shape[-1]).max(axis=1) / size[:, None]).max(axis=0)
        scaled = np.abs(dZ - dZ0).reshape(len(FREQS), -1, dZ.shape[-1]).max(axis=1) / size[:, None]
        assert np.max(scaled.max(axis=0) / top) < 1e-7
        assert info.converged and info0.converged  # (the dimensions may differ: both stop at the round-off floor)
    recycle.forget(model)
