"""The modal outputs the adaptive loop emulates: their layout, and how many modes."""

from __future__ import annotations

import numpy as np
import pytest

from mrgp_core.modal_outputs import ModalLayout, modes_to_emulate


def layout(rng):
    omega = 2 * np.pi * np.repeat([100.0, 110.0, 290.0], 2)
    channel = np.tile([0, 2], 3)
    return ModalLayout(omega, channel, 3, (0.01, 1e-4), 2)


def test_outputs_give_back_the_receptance_they_were_made_from(rng):
    lay = layout(rng)
    omega2 = (2 * np.pi * np.array([[112.0, 291.0], [150.0, 350.0]])) ** 2
    P = rng.normal(size=(2, 2, 3))
    Z = rng.normal(size=(2, 6)) + 1j * rng.normal(size=(2, 6))
    Y = lay.outputs(omega2, P, Z)
    assert Y.shape == (2, lay.n_outputs) and lay.n_outputs == 2 + 6 + 12
    np.testing.assert_allclose(Y[:, :2], omega2)  # the squared frequencies lead
    np.testing.assert_allclose(lay.receptance(Y), Z, rtol=1e-12, atol=1e-15)


def test_the_modes_part_is_the_damped_single_mode_formula(rng):
    lay = layout(rng)
    omega2, P = np.array([4e5, 3e6]), np.arange(6.0).reshape(2, 3)
    a, b = lay.damping
    w = lay.omega
    expected = sum(P[r, lay.channel] / (omega2[r] - w**2 + 1j * w * (a + b * omega2[r])) for r in range(2))
    np.testing.assert_allclose(lay.terms(omega2, P), expected, rtol=1e-14)


def test_a_wrong_output_count_is_refused_with_the_layout(rng):
    with pytest.raises(ValueError, match="expected 20 outputs per row .2 modes, 3 channels, 6 values., got 19"):
        layout(rng).receptance(np.zeros((1, 19)))


@pytest.mark.parametrize("nominal, highest, available, expected", [
    ([148.3, 353.4, 554.6, 741.9], 295.0, 30, 3),  # the benchmark: 2 modes below 1.5 x 295 Hz, plus one
    ([500.0, 900.0], 100.0, 10, 1),  # the band below the first mode: the first mode alone
    ([10.0, 20.0, 30.0], 100.0, 3, 3),  # every mode the model has
    ([148.3, 353.4, 554.6, 741.9, 750.2, 1171.5], 400.0, 30, 5),  # the hammer band: the close pair taken whole
])
def test_modes_to_emulate(nominal, highest, available, expected):
    assert modes_to_emulate(np.array(nominal), highest, available) == expected
