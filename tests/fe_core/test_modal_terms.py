"""Modal terms of an FE run (what the adaptive loop's emulator learns) against a dense eigensolution."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.linalg as sla

from fe_core.io import read_model
from mrgp_core.modal_outputs import ModalLayout
from tests.fe_core.test_model import clamped_strip

#: Rayleigh damping given to the strip (its own is zero): 2-4 % of critical in its lowest modes.
DAMPING = (20.0, 2e-5)


def strip():
    """The clamped strip of test_model, not square (a square one has pairs of equal modes: P is then not unique)."""
    return dataclasses.replace(clamped_strip(8, width=0.03), damping=DAMPING)


def dense_modes(model, theta):
    w2, V = sla.eigh(model.stiffness(theta).toarray(), model.mass().toarray())
    return w2, V


def test_lowest_modes_match_a_dense_eigensolution():
    model = strip()
    theta = np.array([0.3])
    omega2, P = model.modal_terms(theta, 5)
    w2, V = dense_modes(model, theta)
    np.testing.assert_allclose(omega2, w2[:5], rtol=1e-9)
    reference = model.read_outputs(V[:, :5].T) * (V[:, :5].T @ model.combined_load())[:, None]
    np.testing.assert_allclose(P, reference, rtol=1e-7, atol=1e-9 * np.abs(reference).max())


def test_all_modes_rebuild_the_damped_receptance_exactly():
    """With C = a M + b K the modal sum over every mode is the direct solve's receptance."""
    model = strip()
    theta = np.array([-0.4])
    freqs = np.array([5.0, 40.0, 118.0, 700.0])
    w2, V = dense_modes(model, theta)
    P = model.read_outputs(V.T) * (V.T @ model.combined_load())[:, None]
    layout = ModalLayout(2 * np.pi * freqs, np.zeros(4, int), 1, DAMPING, len(w2))
    Z = model.frf(theta, freqs, method="direct")[:, 0]
    np.testing.assert_allclose(layout.terms(w2, P), Z, rtol=1e-8)


def test_channels_pick_the_participations_of_their_reference():
    benchmark_model = read_model(Path(__file__).resolve().parents[2] / "data" / "benchmark" / "model.toml")
    theta = np.zeros(6)
    _, combined = benchmark_model.modal_terms(theta, 3)
    _, channels = benchmark_model.modal_terms(theta, 3, (np.arange(6), np.zeros(6, int)))
    np.testing.assert_array_equal(channels, combined)  # excitation 0 of the benchmark is the combined load
    # The hammer (excitation 1) is a unit load at sensor 5 and the combined load the sum over the sensors:
    # sum_s phi_s phi_5 over the hammer's channels is sensor 5's participation under the combined load.
    _, hammer = benchmark_model.modal_terms(theta, 3, (np.arange(6), np.ones(6, int)))
    np.testing.assert_allclose(hammer.sum(axis=1), combined[:, 4], rtol=1e-9)
    assert np.all(hammer[:, 4] > 0)  # a driving point participates positively in every mode
