"""The shell example (data/examples/shell_panel): a CalculiX deck of S8R shells, route A.

References: ccx's own steady-state FRF of the model's deck (modal superposition, the model file's Rayleigh
damping) for the imported model, and ``truth.json`` for the update, whose measured data are ccx's FRF of
a twice finer mesh with 1 % noise (``python -m benchmarks.make.shell_panel``).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from fe_core.io import read_model
from fe_core.io.calculix import read_deck, read_steady_state, run_ccx
from fe_core.inference.intervals import parameter_intervals
from flows.config import REPO
from tasks.io.measured import read_measured

EXAMPLE = REPO / "data" / "examples" / "shell_panel"
pytestmark = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")


def test_the_imported_model_has_ccxs_own_frf_at_the_sensors(tmp_path):
    model = read_model(EXAMPLE / "model.toml")
    toml = (EXAMPLE / "model.toml").read_text()
    nodes = [int(line.split("=")[1]) for line in toml.splitlines() if line.startswith("node =")]
    directions = [line.split('"')[1] for line in toml.splitlines() if line.startswith("direction =")][:len(nodes)]
    deck = read_deck(EXAMPLE / "panel.inp")
    tip = deck.nsets["TIP_CORNER"][0]
    a, b = model.damping
    steps = (f"*NSET, NSET=S\n{', '.join(map(str, nodes))}\n*STEP\n*FREQUENCY, STORAGE=YES\n60\n*CLOAD\n{tip}, 3, 0.\n"
             "*END STEP\n*STEP\n*STEADY STATE DYNAMICS\n50., 120., 3, 1.\n"
             f"*MODAL DAMPING, RAYLEIGH\n,,{a!r},{b!r}\n*CLOAD\n{tip}, 3, 1.\n*NODE PRINT, NSET=S\nU\n*END STEP\n")
    (tmp_path / "ssd.inp").write_text(deck.text(steps=steps))
    run_ccx(tmp_path, "ssd", timeout=120)
    freqs, disp = read_steady_state(tmp_path / "ssd.dat")
    theirs = np.column_stack([disp[n][:, "xyz".index(d)] for n, d in zip(nodes, directions)])
    ours = model.frf(np.zeros(model.n_segments), freqs)
    assert ours.shape == theirs.shape and freqs.size == 7  # 50, 120 Hz and 3 points between and at the natural frequencies 71, 83 Hz
    # ccx: 60 of ~3200 modes (truncation) and 7 printed digits; the largest responses (peaks) to 0.5 %
    big = np.abs(theirs) > 0.05 * np.abs(theirs).max()
    np.testing.assert_allclose(ours[big], theirs[big], rtol=5e-3)


def test_route_a_recovers_the_segment_moduli_from_ccxs_finer_mesh():
    truth = json.loads((EXAMPLE / "truth.json").read_text())
    model = read_model(EXAMPLE / "model.toml")
    measured = read_measured(EXAMPLE / "measured.csv")
    # Gauss-Newton with exact Jacobians of the imported matrices, from the nominal model
    result = parameter_intervals(model, measured.frequencies_hz, measured.amplitude, np.zeros(4), -0.5, 0.5,
                                 noise=truth["noise"], max_jacobians=8)
    estimate = result.intervals.estimate
    assert np.max(np.abs(estimate - truth["parameters"])) < 0.02, estimate
    # the 1 % noise alone would allow +-0.001; what is left is the model mesh's discretisation (0.1 % in the
    # first natural frequencies, truth.json), which the intervals do not know of
    assert np.all(result.intervals.high - result.intervals.low < 0.005)


def test_model_vtu_of_the_deck_has_its_shells_segments_and_ccxs_modes(tmp_path):
    """The run's model.vtu for a deck: every S8R shell as a quad8 cell of its segment, modes at ccx's
    natural frequencies (*FREQUENCY on the same deck), read back by meshio."""
    import meshio

    from fe_core.io.vtu import parse_mode_field
    from fe_core.io.calculix import read_eigenfrequencies
    from tasks.model_vtu import write_model_vtu

    model = read_model(EXAMPLE / "model.toml")
    alpha = [0.1, -0.1, 0.2, 0.0]
    path = write_model_vtu(tmp_path, model, {f"alpha_{i + 1}": a for i, a in enumerate(alpha)}, n_modes=3)
    grid = meshio.read(path)
    deck = read_deck(EXAMPLE / "panel.inp")
    assert [c.type for c in grid.cells] == ["quad8"] and len(grid.cells[0].data) == len(deck.elements) == 144
    assert grid.points.shape == (len(deck.nodes), 3)
    seg = grid.cell_data["segment"][0]
    assert [int(np.sum(seg == k)) for k in range(4)] == [len(deck.elsets[s]) for s in
                                                         ("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH")]
    np.testing.assert_allclose(grid.cell_data["alpha"][0], np.array(alpha)[seg])
    ours = sorted(parse_mode_field(name)[1] for name in grid.point_data)
    # the deck with the factors as moduli: one material per section
    cards = []
    for k, (s, a) in enumerate(zip(("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH"), alpha)):
        cards.append(f"*MATERIAL, NAME=M{k}\n*ELASTIC\n{7e10 * (1 + a)!r}, 0.33\n*DENSITY\n2700.")
    params = {deck.section_of(s): {"MATERIAL": f"M{k}"} for k, s in
              enumerate(("ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH"))}
    text = deck.text(params=params, extra="\n".join(cards), steps="*STEP\n*FREQUENCY\n3\n*END STEP\n")
    (tmp_path / "f.inp").write_text(text)
    run_ccx(tmp_path, "f", timeout=120)
    np.testing.assert_allclose(ours, read_eigenfrequencies(tmp_path / "f.dat"), rtol=2e-6)
    tip = sorted(deck.nodes).index(deck.nsets["TIP_CORNER"][0])
    assert all(np.linalg.norm(v[tip]) > 0 for v in grid.point_data.values())   # the free corner moves


def test_the_closure_effect_library_builds_on_a_deck_model():
    """The hybrid's evidence screen and the closure build their effect library on any model; on a deck the
    sensors read the mean of ccx's expanded shell nodes, which are no DOF-table node of their own (this
    raised KeyError before, and the update on the example stopped in its evidence stage)."""
    from fe_core.closure.effects import build_library

    model = read_model(EXAMPLE / "model.toml")
    library = build_library(model)
    kinds = {effect.kind for effect in library}
    assert "point_mass" in kinds and "sensor_mass" in kinds
    point = next(effect for effect in library if effect.kind == "point_mass")
    assert len(point.locations()) > 10
