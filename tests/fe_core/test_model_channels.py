"""Measured channels on the FE side: several references through one solve, test nodes in the model file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from fe_core.io import read_model

REPO = Path(__file__).resolve().parents[2]
FREQS = np.array([50.0, 112.0, 291.0, 400.0])
#: The FE core's promise between solution methods and load layouts (README: 1e-9 Krylov vs direct).
METHOD_RTOL = 1e-9


@pytest.fixture(scope="module")
def model():
    return read_model(REPO / "data" / "benchmark" / "model.toml")


def test_the_benchmark_file_keeps_every_excitation_and_its_test_nodes(model):
    assert model.excitation_names == ["combined", "hammer"] and model.excitation_name == "combined"
    assert model.sensor_test_dofs == [(j, 3) for j in range(1, 7)]
    assert model.excitation_test_dofs == [None, (5, 3)]
    np.testing.assert_array_equal(model.excitation_loads[:, 0], model.load)


def test_hammer_channels_are_a_column_of_the_frf_matrix(model):
    """The hammer at s5 along z is sensor 5's unit load: its channels are frf_matrix's column 5."""
    Z = model.frf_channels(ALPHA_ACTUAL, FREQS, np.arange(6), np.full(6, 1))
    H = model.frf_matrix(ALPHA_ACTUAL, FREQS, method="direct")[:, :, 4]
    assert np.max(np.abs(Z - H) / np.abs(H).max(axis=1, keepdims=True)) <= METHOD_RTOL


def test_several_references_in_one_solve_equal_one_solve_each(model):
    responses, references = np.array([0, 4, 2, 4, 5]), np.array([1, 0, 1, 1, 0])
    Z = model.frf_channels(ALPHA_ACTUAL, FREQS, responses, references)
    combined = model.frf(ALPHA_ACTUAL, FREQS)
    hammer = model.frf_channels(ALPHA_ACTUAL, FREQS, np.arange(6), np.ones(6, int))
    expected = np.where(references == 0, combined[:, responses], hammer[:, responses])
    assert np.max(np.abs(Z - expected) / np.abs(expected)) <= METHOD_RTOL


def test_default_channels_are_the_models_frf_exactly(model):
    Z = model.frf_channels(ALPHA_ACTUAL, FREQS, np.arange(6), np.zeros(6, int))
    np.testing.assert_array_equal(Z, model.frf(ALPHA_ACTUAL, FREQS))


def test_bad_channel_indices_are_refused(model):
    with pytest.raises(ValueError, match="excitation indices"):
        model.frf_channels(ALPHA_ACTUAL, FREQS, [0], [2])
    with pytest.raises(ValueError, match="sensor indices"):
        model.frf_channels(ALPHA_ACTUAL, FREQS, [6], [0])
