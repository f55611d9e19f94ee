"""Modes identified from the benchmark's hammer FRFs with sdypy-EMA (LSCF/LSFD), then the modal update
(``python -m flows.update --identify-modes``): against the SPEC's independent frequencies, the benchmark's
Rayleigh damping and its actual alpha."""

from __future__ import annotations

import json

import numpy as np

from fe_core.benchmark import ALPHA_ACTUAL, DAMPING
from flows import update
from flows.config import REPO
from tasks.io.measured.modes import read_modes


def test_hammer_frfs_give_two_modes_and_the_update_on_them_covers_the_actual_alpha(tmp_path, prefect_harness,
                                                                                  check_summary):
    argv = ["--model", "data/benchmark/model.toml", "--measured", "data/benchmark/hammer.uff", "--identify-modes",
            "20-400", "--starts", "1", "--runs-dir", str(tmp_path), "--run-id", "r",
            "--true-parameters=" + ",".join(str(v) for v in ALPHA_ACTUAL)]
    assert update.main(argv) == 0
    summary = check_summary(tmp_path / "r")  # the one shape, with the identification's fields
    modes = read_modes(tmp_path / "r" / "identified_modes.uff")
    expected = json.loads((REPO / "data" / "benchmark" / "expected.json").read_text())["actual"]["frequencies_Hz"]
    # hammer.uff carries 1 % FRF noise: the poles come within 0.3 % of the SPEC's frequencies
    np.testing.assert_allclose(modes.frequencies_hz, expected[:2], rtol=3e-3)
    # Rayleigh damping: zeta = a / (2 w) + b w / 2, within 5 %
    w = 2 * np.pi * np.asarray(expected[:2])
    np.testing.assert_allclose(modes.damping, DAMPING[0] / (2 * w) + DAMPING[1] * w / 2, rtol=0.05)
    assert modes.dofs == ["1:+z", "2:+z", "3:+z", "4:+z", "5:+z", "6:+z"]
    st = summary["stabilisation"]
    # the noise peaks near 20 Hz have no stable pole and are dropped; both modes are stable at most orders
    assert st["dropped_peaks_hz"] and max(st["dropped_peaks_hz"]) < 50
    assert min(st["stable_orders"]) >= 30
    # first bending has no node between the clamps: every test DOF moves the same way
    assert np.all(modes.shapes[0] * modes.shapes[0][np.argmax(np.abs(modes.shapes[0]))] > 0)
    # two modes at six test DOFs determine the six factors: all inside their 95 % intervals
    assert len(summary["paired_modes"]) == 2 and all(summary["intervals_contain_truth"].values())
