"""Route B: ccx as a black box on shell thicknesses (fe_core/io/calculix/blackbox.py).

The measured FRF is ccx's own at true thickness factors on the example's deck, with 1 % noise (a test of the
loop, not of the model: the same mesh); the update starts from the deck's nominal thicknesses and uses
finite differences only.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from fe_core.inference.laplace import laplace_intervals
from fe_core.io.calculix import CcxError, read_deck
from fe_core.io.calculix.blackbox import DeckFRF, fd_gauss_newton
from fe_core.io.calculix.deck import NumberRef
from flows.config import REPO

pytestmark = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")
EXAMPLE = REPO / "data" / "examples" / "shell_panel"
TRUTH = np.array([0.05, -0.08, 0.10, -0.05])


def _model(timeout=120.0) -> DeckFRF:
    deck = read_deck(EXAMPLE / "panel.inp")
    numbers = [NumberRef(deck.section_of(s), 0, 0) for s in ("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH")]
    toml = (EXAMPLE / "model.toml").read_text()
    nodes = [int(line.split("=")[1]) for line in toml.splitlines() if line.startswith("node =")]
    dirs = [line.split('"')[1] for line in toml.splitlines() if line.startswith("direction =")][:len(nodes)]
    freqs = np.array([f * r for f in (71.1, 82.7, 185.5) for r in (0.9, 0.97, 1.03, 1.1)])
    return DeckFRF(deck, numbers, [(n, "xyz".index(d)) for n, d in zip(nodes, dirs)],
                   (deck.nsets["TIP_CORNER"][0], 2), (2.0, 2e-6), freqs, n_modes=30, timeout=timeout)


def test_thicknesses_from_finite_differences_within_0_02_and_intervals_covering(tmp_path):
    model = _model()
    Z = model.run(TRUTH, tmp_path / "truth")
    rng = np.random.default_rng(3)
    measured = np.abs(Z) * (1 + 0.01 * rng.standard_normal(Z.shape))
    result = fd_gauss_newton(model, measured, np.zeros(4), -0.3, 0.3, tmp_path / "update", max_iterations=8)
    assert not result.failures
    assert np.max(np.abs(result.theta - TRUTH)) < 0.02, result.theta
    iv = laplace_intervals(result.residual, result.jacobian, result.theta, noise=0.01)
    assert np.all((iv.low <= TRUTH) & (TRUTH <= iv.high)), (iv.low, iv.high)
    # one parallel round of m + 1 runs per Jacobian, one run per trial step
    assert result.fe_runs >= 2 * 5 and result.rounds < result.fe_runs


def test_a_complete_run_folder_is_reused_and_an_incomplete_one_run_again(tmp_path):
    model = _model()
    folder = tmp_path / "run-0"
    first = model.run(np.zeros(4), folder)
    stamp = (folder / "deck.log").stat().st_mtime_ns
    np.testing.assert_array_equal(model.run(np.zeros(4), folder), first)
    assert (folder / "deck.log").stat().st_mtime_ns == stamp          # not run again
    (folder / "done.json").unlink()                                     # killed before it was marked complete
    np.testing.assert_allclose(model.run(np.zeros(4), folder), first, rtol=1e-12)
    assert (folder / "deck.log").stat().st_mtime_ns != stamp


def test_a_failed_run_is_a_recorded_failure_quoting_the_solver(tmp_path):
    model = _model(timeout=0.01)
    with pytest.raises(CcxError, match="ccx ran past its time limit of 0.01 s"):
        model.run(np.zeros(4), tmp_path / "slow")
    with pytest.raises(CcxError, match="failed: .*time limit"):
        fd_gauss_newton(model, np.ones((12, 7)), np.zeros(4), -0.3, 0.3, tmp_path / "update", max_iterations=1)
