"""Route B's model (fe_core/io/calculix/blackbox_model.py) against route A on the same deck.

A parameter on the material's Young's modulus (``material = "ALU"``, ``card = "*ELASTIC"``: the general form) is
linear in K, so route A (ccx's exported matrices, our exact Jacobian) gives an independent reference for route B's
FRF (ccx's modal steady state) and its forward-difference derivative: the panel's four sections share the material,
so route B's one derivative is the sum of route A's four segment derivatives.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from benchmarks.make import shell_panel

pytestmark = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")

HEAD = """units = "SI"
solver = "calculix"
deck = "panel.inp"
[damping]
a = 2.0
b = 2e-6
"""


def test_forward_differences_on_a_modulus_match_route_a_exact_jacobian(tmp_path, monkeypatch):
    from fe_core.io import read_model
    from fe_core.solvers.sensitivity import frf_jacobian

    monkeypatch.setenv("FE_CALCULIX_CACHE", str(tmp_path / "cache"))
    cards, ids = shell_panel.panel(4, 4)
    (tmp_path / "panel.inp").write_text(cards)
    tail = "".join(f'\n[[sensors]]\nnode = {ids[shell_panel.point(u, v)]}\ndirection = "{d}"\n'
                   for u, v, d in shell_panel.SENSORS) + '\n[[excitations]]\nnset = "TIP_CORNER"\ndirection = "z"\n'
    (tmp_path / "a.toml").write_text(HEAD + "".join(f'\n[[segments]]\nset = "{s}"\n' for s in shell_panel.SEGMENTS)
                                     + tail)
    (tmp_path / "b.toml").write_text("n_modes = 40\n" + HEAD + '\n[[parameters]]\nname = "E"\nmaterial = "ALU"\n'
                                     'card = "*ELASTIC"\n' + tail)
    route_a, route_b = read_model(tmp_path / "a.toml"), read_model(tmp_path / "b.toml").with_workdir(tmp_path / "fe")
    f1 = route_b.natural_frequencies(np.zeros(1), 1)[0]
    freqs = f1 * np.array([0.9, 0.95, 1.05, 1.1])
    theta = 0.05
    Za, dZa = frf_jacobian(route_a, np.full(4, theta), freqs)
    Zb, dZb = frf_jacobian(route_b, np.array([theta]), freqs)        # dispatches to the forward differences
    # the FRF: ccx's modal superposition (40 modes, no residual correction) vs the full solve (0.08 % measured)
    np.testing.assert_allclose(np.abs(Zb), np.abs(Za), rtol=2e-3)
    # d ln|Z| / d theta: forward difference (step 1e-3: truncation ~ h / (4 delta) = 0.5 % at delta = 5 % from the
    # resonance) of the truncated modal sum vs the exact derivative summed over the segments (2.0 % measured)
    ga = np.real(dZa.sum(axis=-1) / Za)
    gb = np.real(dZb[..., 0] / Zb)
    np.testing.assert_allclose(gb, ga, rtol=3e-2, atol=3e-2 * np.max(np.abs(ga)))
