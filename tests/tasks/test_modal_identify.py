"""Modes identified from the benchmark's hammer FRFs with sdypy-EMA (LSCF/LSFD) against the SPEC's
independent frequencies and the Rayleigh damping of the benchmark."""

from __future__ import annotations

import json

import numpy as np

from fe_core.benchmark import DAMPING
from flows.config import REPO
from tasks.io.measured import read_measured
from tasks.modal_identify import identify_modes


def test_hammer_frfs_give_the_two_modes_below_400_hz():
    modes, stabilisation = identify_modes(read_measured(REPO / "data" / "benchmark" / "hammer.uff"), 20, 400)
    expected = json.loads((REPO / "data" / "benchmark" / "expected.json").read_text())["actual"]["frequencies_Hz"]
    # hammer.uff carries 1 % FRF noise: the poles come within 0.3 % of the SPEC's frequencies
    np.testing.assert_allclose(modes.frequencies_hz, expected[:2], rtol=3e-3)
    # Rayleigh damping: zeta = a / (2 w) + b w / 2 (of the damped pole: within 5 %)
    w = 2 * np.pi * np.asarray(expected[:2])
    np.testing.assert_allclose(modes.damping, DAMPING[0] / (2 * w) + DAMPING[1] * w / 2, rtol=0.05)
    assert modes.dofs == ["1:+z", "2:+z", "3:+z", "4:+z", "5:+z", "6:+z"]
    # the noise peaks near 20 Hz have no stable pole and are dropped; both modes are stable at most orders
    assert stabilisation["dropped_peaks_hz"] and max(stabilisation["dropped_peaks_hz"]) < 50
    assert min(stabilisation["stable_orders"]) >= 30
    # first bending has no node between the clamps: every test DOF moves the same way
    assert np.all(modes.shapes[0] * modes.shapes[0][np.argmax(np.abs(modes.shapes[0]))] > 0)
