"""The large example's generator (``python -m benchmarks.make.large``) on a small mesh of the same panel.

The panel at mesh size 80 mm (9,030 free DOFs) goes through the whole generator once: gmsh mesh, scikit-fem
assembly at the true factors, Lanczos modes, the modal sum with the deflated remainder, noise, the files.
The data are checked against references the generator does not produce: ``fe_core``'s own reading and
assembly of the written model file (its FRF at the truth, by its default solver), and a direct solve of
scikit-fem's matrices at single lines.
"""

from __future__ import annotations

import hashlib
import json
import tomllib

import numpy as np
import pytest

from benchmarks.make.large import ALPHA_RANGE, N_LINES, NOISE, TEMPLATE, geometry
from benchmarks.make.large.__main__ import add_noise, frequencies, generate
from benchmarks.make.large.synthesis import Cholesky, direct_frf, modal_frf
from fe_core.io import read_model
from tasks.io.measured import read_measured

SIZE, PER_CIRCLE = 0.08, 6
#: Lines of the direct check: near the first resonance (249 Hz), between modes, the band's top.
CHECK_LINES = (18, 150, N_LINES - 1)


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("large")
    state = generate(1e4, out, size=SIZE, per_circle=PER_CIRCLE)
    truth = json.loads((out / "truth.json").read_text())
    return out, state["generation"], state["panel"], state["H"], truth, state


def _far_from_antiresonances(H: np.ndarray) -> np.ndarray:
    """Lines where a channel is above 1 % of its median (relative errors grow at its zeros; here the largest
    error of all lines is 1.4e-8, on a line 0.08 times its channel's median)."""
    return np.abs(H) > 0.01 * np.median(np.abs(H), axis=0)


def test_the_files_and_the_truth(generated):
    out, generation, panel, H, truth, _ = generated
    assert sorted(p.name for p in out.iterdir()) == ["generation.json", "measured.csv", "model.toml", "panel.msh",
                                                     "truth.json"]
    assert (out / "model.toml").read_text() == TEMPLATE.read_text()
    assert generation["free_dofs"] == panel.n_dofs == truth["free_dofs"] == 9030
    alpha = np.array(list(truth["alpha"].values()))
    assert list(truth["alpha"]) == list(geometry.SEGMENTS)
    assert np.all((alpha >= ALPHA_RANGE[0]) & (alpha <= ALPHA_RANGE[1])) and np.ptp(alpha) > 0.1
    # The holes are polygons at this mesh size (straight-sided cells): 0.36 % more steel than the CAD model.
    assert truth["mass_kg"] == pytest.approx(geometry.VOLUME * 7850.0, rel=5e-3)
    assert truth["files"]["panel.msh"] == _sha(out / "panel.msh")
    assert truth["files"]["measured.csv"] == _sha(out / "measured.csv")
    modes = truth["modes"]
    assert modes["natural_hz"][-1] < modes["cutoff_hz"] < modes["next_hz"]
    assert modes["cutoff_hz"] > 1.5 * frequencies()[-1]


def test_the_mesh_is_the_same_at_every_run(generated, tmp_path):
    out = generated[0]
    points = np.array([s["point"] for s in tomllib.loads(TEMPLATE.read_text())["sensors"]]
                      + [e["point"] for e in tomllib.loads(TEMPLATE.read_text())["excitations"]])
    again = tmp_path / "panel.msh"
    geometry.build(again, SIZE, points, PER_CIRCLE)
    assert _sha(again) == _sha(out / "panel.msh")


def test_the_measured_file_is_the_noise_free_frf_times_the_seeded_noise(generated):
    out, _, panel, H, _, _ = generated
    measured = read_measured(out / "measured.csv")
    assert list(measured.responses) == panel.sensor_names
    assert set(measured.references) == {panel.excitation_name}
    np.testing.assert_allclose(measured.frequencies_hz, frequencies())
    factor = measured.complex_frf / H
    np.testing.assert_allclose(factor, add_noise(np.ones_like(H)), rtol=1e-10)
    assert np.sqrt(np.mean(np.abs(factor - 1) ** 2)) == pytest.approx(NOISE, rel=0.05)


def test_fe_core_reads_the_model_file_and_gives_the_same_frf_at_the_truth(generated):
    out, _, panel, H, truth, _ = generated
    model = read_model(out / "model.toml")
    assert model.n_dofs == panel.n_dofs
    assert model.segment_names == list(truth["alpha"])
    assert model.sensor_names == panel.sensor_names
    alpha = np.array(list(truth["alpha"].values()))
    freqs = frequencies()
    Z = model.frf(alpha, freqs)  # fe_core's reader, tet10 element matrices, assembly and FRF solver
    far = _far_from_antiresonances(H)
    error = np.abs(Z / H - 1)
    assert far.mean() > 0.99
    assert error[far].max() < 1e-6, error[far].max()
    # The comparison sees a 1 % change of one segment's stiffness: the data are the truth's, not any model's.
    wrong = alpha.copy()
    wrong[6] += 0.01
    assert np.abs(model.frf(wrong, freqs) / H - 1)[far].max() > 1e-3


def test_modes_and_remainder_equal_a_direct_solve(generated):
    _, _, panel, H, truth, state = generated
    lines = frequencies()[list(CHECK_LINES)]
    direct = direct_frf(panel.K, panel.M, panel.outputs, panel.load, lines, panel.damping)
    np.testing.assert_allclose(H[list(CHECK_LINES)], direct, rtol=1e-7, atol=0)
    # Without the remainder's frequency terms (the static remainder alone) the sum is visibly off: the
    # deflated series is what closes the gap to the direct solve.
    solve = Cholesky(panel.K)
    static, _ = modal_frf(panel.K, panel.M, solve, state["omega2"], state["phi"], panel.outputs, panel.load, lines,
                          panel.damping, max_terms=1)
    solve.free()
    assert np.abs(static / direct - 1).max() > 1e-5


def test_an_undeclared_point_mass_is_added_at_the_nearest_node_only(generated):
    """``--point-mass``: scikit-fem's M gains the share of the panel's mass on the three translations of the
    node nearest MASS_AT (located here by fe_core's own reading of the mesh), and nothing else changes."""
    from benchmarks.make.large import MASS_AT
    from benchmarks.make.large.assembly import assemble_panel

    out, _, panel, _, truth, _ = generated
    spec = tomllib.loads(TEMPLATE.read_text())
    alpha = np.array(list(truth["alpha"].values()))
    heavy = assemble_panel(spec, out / "panel.msh", alpha, (MASS_AT, 0.03))
    assert (heavy.K != panel.K).nnz == 0
    added = (heavy.M - panel.M).tocoo()
    added.eliminate_zeros()
    assert added.nnz == 3 and np.all(added.row == added.col)
    np.testing.assert_allclose(added.data, 0.03 * truth["mass_kg"], rtol=1e-7)  # truth.json rounds to 1e-6 kg
    # The same node by fe_core: its free rows are the rows the mass went to (both number DOFs node-major).
    model = read_model(out / "model.toml")
    node = int(model.mesh.nearest_node(MASS_AT, atol=None))
    np.testing.assert_allclose(model.node_position(node), heavy.mass_node["xyz_m"], atol=1e-12)
    assert heavy.mass_node["mass_kg"] == pytest.approx(0.03 * truth["mass_kg"], rel=1e-7)
