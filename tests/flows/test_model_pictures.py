"""Every run writes ``<run>/model.vtu``; the report draws the mesh (or says why it cannot)."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import meshio
import numpy as np
import pandas as pd
import pytest

from flows import report, update
from fe_core.io import read_model
from flows.config import REPO
from tasks.model_vtu import VTU_NAME, factors_from_parameters, write_model_vtu
from tasks.report.mesh import FACTORS_PNG, SEGMENTS_PNG

MATRICES = REPO / "data" / "examples" / "cantilever_matrices"
TRUTH = np.array([0.2, -0.15])
FREQS = np.array([150.0, 220.0, 260.0, 320.0, 360.0, 420.0])
#: One iteration of q FE runs, no polish: what is tested here is written after any update.
CHEAPEST = dict(max_iterations=1, polish=False)
#: Shift-invert Lanczos against a dense generalized eigensolver (see tests/fe_core/test_vtu.py).
FREQ_RTOL = 1e-8


def _measured(folder: Path, write_box_model) -> Path:
    """Amplitudes of a finer mesh of the same box (twice the cells in each direction) at TRUTH."""
    from fe_core.io import read_model

    fine = read_model(write_box_model(folder / "fine", cells=(12, 4, 2)))
    Z = np.abs(fine.frf(TRUTH, FREQS))  # (p, 3)
    table = pd.DataFrame({"sensor": np.tile([1, 2, 3], FREQS.size), "frequency_hz": np.repeat(FREQS, 3),
                          "amplitude": Z.ravel()})
    path = folder / "measured.csv"
    table.to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def box_run(tmp_path_factory, prefect_harness, reduced_settings_frozen, box_model_writer):
    tmp = tmp_path_factory.mktemp("pictures")
    model = box_model_writer(tmp / "box")
    settings = dict(reduced_settings_frozen, **CHEAPEST)
    config = update.UpdateConfig(run_id="box", runs_dir=str(tmp / "runs"), model=str(model),
                                 measured=str(_measured(tmp, box_model_writer)), **settings)
    summary = update.update_flow(config)
    return Path(summary["run_folder"]), summary, model


@pytest.mark.slow
def test_the_run_writes_the_updated_model_as_vtu(box_run):
    from fe_core.io import read_model
    from fe_core.io.vtu import parse_mode_field

    root, summary, model_file = box_run
    model = read_model(model_file)
    back = meshio.read(root / VTU_NAME)
    assert not list(root.glob(".*.tmp"))
    assert len(back.cells) == 1 and len(back.cells[0].data) == model.mesh.n_cells == 72
    seg = back.cell_data["segment"][0]
    np.testing.assert_array_equal(seg, model.cell_segment)
    alpha = np.array([summary["parameters"]["alpha_1"], summary["parameters"]["alpha_2"]])
    cell_alpha = back.cell_data["alpha"][0]
    np.testing.assert_array_equal(cell_alpha[seg >= 0], alpha[seg[seg >= 0]])
    assert np.all(np.isnan(cell_alpha[seg < 0])) and "gamma" not in back.cell_data
    # The modes are those of the updated model: a dense solve of K(alpha), M at the summary's alpha.
    import scipy.linalg

    fields = sorted((parse_mode_field(n), f) for n, f in back.point_data.items())
    freqs = np.array([f for (_, f), _ in fields])
    assert freqs.size == 6
    w2 = scipy.linalg.eigh(model.stiffness(alpha).toarray(), model.mass().toarray(), eigvals_only=True,
                           subset_by_index=[0, 5])
    np.testing.assert_allclose(freqs, np.sqrt(w2) / (2 * np.pi), rtol=FREQ_RTOL)
    K, M = model.stiffness(alpha), model.mass()
    for (_, f), field in fields:
        phi = field.reshape(-1)[model.free_dofs]
        r = K @ phi - (2 * np.pi * f) ** 2 * (M @ phi)
        assert np.linalg.norm(r) <= 1e-8 * np.linalg.norm(K @ phi)


@pytest.mark.slow
def test_the_report_draws_the_mesh_and_its_factors(box_run):
    root, summary, _ = box_run
    page = Path(report.report_flow(str(root)))
    text = page.read_text()
    for name in (SEGMENTS_PNG, FACTORS_PNG):
        png = page.parent / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000, name
        assert f'alt="{name}"' in text
    assert "Mesh, segments, sensors and updated factors" in text
    assert "72 cells" in text and "24 cells in the fixed remainder" in text
    assert "No mesh pictures" not in text


@pytest.mark.slow
def test_a_matrices_model_gets_no_vtu_and_no_mesh_pictures(tmp_path, prefect_harness, reduced_config, caplog):
    config = reduced_config.replace(model=str(MATRICES / "model.toml"), measured=str(MATRICES / "measured.csv"),
                                    **CHEAPEST)
    with caplog.at_level(logging.INFO):
        summary = update.update_flow(config)
    root = Path(summary["run_folder"])
    assert not (root / VTU_NAME).exists()
    assert any("model.vtu not written" in r.getMessage() and "matrices" in r.getMessage() for r in caplog.records)
    page = Path(report.report_flow(str(root)))
    text = page.read_text()
    assert not (page.parent / SEGMENTS_PNG).exists() and not (page.parent / FACTORS_PNG).exists()
    notes = re.findall(r"<p class='note'>([^<]*No mesh pictures[^<]*)</p>", text)
    assert len(notes) == 1 and "given as matrices" in notes[0]


def _with_masses(model_file: Path, segments=("root", "middle")) -> Path:
    """The box model file with the mass factors of ``segments`` updated too."""
    text = model_file.read_text()
    for name in segments:
        text = text.replace(f'set = "{name}"', f'set = "{name}"\nupdate = ["stiffness", "mass"]')
    model_file.write_text(text)
    return model_file


def test_the_factors_of_a_summary(box_model_file):
    from fe_core.io import read_model

    alpha, gamma = factors_from_parameters({"alpha_1": 0.1, "alpha_2": -0.2}, read_model(box_model_file))
    assert alpha.tolist() == [0.1, -0.2] and gamma is None
    with pytest.raises(ValueError, match="gamma_1: not parameters of the model"):
        factors_from_parameters({"alpha_1": 0.1, "alpha_2": -0.2, "gamma_1": 0.3}, read_model(box_model_file))
    model = read_model(_with_masses(box_model_file, ("middle",)))  # gamma_2 only: gamma_1 stays 0
    alpha, gamma = factors_from_parameters({"alpha_1": 0.1, "alpha_2": -0.2, "gamma_2": 0.3}, model)
    assert alpha.tolist() == [0.1, -0.2] and gamma.tolist() == [0.0, 0.3]
    with pytest.raises(ValueError, match="lack gamma_2"):
        factors_from_parameters({"alpha_1": 0.1, "alpha_2": -0.2}, model)
    with pytest.raises(ValueError, match="lack alpha_1, alpha_2"):
        factors_from_parameters({"gamma_2": 0.3}, model)


def test_the_vtu_is_renamed_into_place_and_gamma_is_written(box_model_file, tmp_path):
    root = tmp_path / "run"
    root.mkdir()
    path = write_model_vtu(root, read_model(_with_masses(box_model_file)), {"alpha_1": 0.1, "alpha_2": 0.2,
                                                                      "gamma_1": -0.1, "gamma_2": 0.05}, n_modes=2)
    assert path == root / VTU_NAME and sorted(p.name for p in root.iterdir()) == [VTU_NAME]
    back = meshio.read(path)
    assert set(back.cell_data) == {"segment", "alpha", "gamma"} and len(back.point_data) == 2


def test_an_interrupted_write_leaves_no_model_vtu_and_its_temporary_file_is_cleared(box_model_file, tmp_path,
                                                                                      monkeypatch):
    from tasks.runstore import RunStore

    root = tmp_path / "run"
    root.mkdir()

    def interrupted(point):
        assert point == f"before-rename:{root / VTU_NAME}"
        temporaries = list(root.glob(f".{VTU_NAME}.*.tmp"))
        assert len(temporaries) == 1 and meshio.read(temporaries[0], file_format="vtu").points.shape[0] > 0
        (root / "left-by-a-kill.tmp").write_bytes(temporaries[0].read_bytes())
        raise KeyboardInterrupt

    monkeypatch.setattr("tasks.runstore.kill_point", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_model_vtu(root, read_model(box_model_file), {"alpha_1": 0.1, "alpha_2": 0.2}, n_modes=1)
    assert sorted(p.name for p in root.iterdir()) == ["left-by-a-kill.tmp"]  # no model.vtu, no temporary
    # A SIGKILL leaves the temporary file; the next run's start removes it (RunStore convention).
    (root / "left-by-a-kill.tmp").rename(root / f".{VTU_NAME}.abc123.tmp")
    assert [p.name for p in RunStore(root).remove_temporaries()] == [f".{VTU_NAME}.abc123.tmp"]


def test_the_view_draws_the_three_sides_of_the_box_that_face_the_viewer(box_model_file):
    """Seen from +x, -y, +z (the default azimuth -58 deg, elevation 24 deg), a box shows exactly one
    of each pair of opposite sides."""
    from fe_core.io import read_model
    from fe_core.surface import face_normals
    from tasks.report.mesh import MeshView

    view = MeshView(read_model(box_model_file))
    a, b, c = 0.3, 0.04, 0.03
    n = view.polygons.shape[1]
    normals = face_normals(view.polygons.reshape(-1, 3), np.arange(len(view.polygons) * n).reshape(-1, n))
    assert normals[:, 0].sum() == pytest.approx(b * c, rel=1e-12)  # the tip x = a
    assert normals[:, 1].sum() == pytest.approx(-a * c, rel=1e-12)  # the side y = 0
    assert normals[:, 2].sum() == pytest.approx(a * b, rel=1e-12)  # the top z = c
    assert np.linalg.norm(normals, axis=1).sum() == pytest.approx(a * b + b * c + c * a, rel=1e-12)
    assert view.n_boundary == 2 * len(view.polygons)
