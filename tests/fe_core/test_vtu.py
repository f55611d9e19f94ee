"""``model.vtu``: segments, updated factors and modes of the updated model, read back with meshio."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest
import scipy.linalg

from fe_core.io import read_model
from fe_core.io.vtu import model_vtu, parse_mode_field

ALPHA = np.array([0.3, -0.4])
GAMMA = np.array([-0.2, 0.1])
N_MODES = 6
#: Shift-invert Lanczos (ARPACK, tol 0: machine precision on the Ritz values) against a dense
#: solve: the frequencies agree to round-off times the condition of the pencil (~1e4 here);
#: the 10 significant digits of the field names add 5e-10.
FREQ_RTOL = 1e-8
#: ||K phi - w^2 M phi|| / ||K phi|| of a converged Ritz pair.
RESIDUAL_RTOL = 1e-8


@pytest.fixture
def model(box_model_file):
    return read_model(box_model_file)


def _round_trip(mesh, tmp_path):
    path = tmp_path / "model.vtu"
    meshio.write(path, mesh)
    return meshio.read(path)


def test_cells_segments_and_factors_read_back(model, tmp_path):
    back = _round_trip(model_vtu(model, ALPHA, GAMMA, N_MODES), tmp_path)
    assert [b.type for b in back.cells] == ["tetra10"]
    np.testing.assert_array_equal(back.cells[0].data, model.mesh.cells)
    np.testing.assert_array_equal(back.points, model.mesh.nodes)
    seg = back.cell_data["segment"][0]
    np.testing.assert_array_equal(seg, model.cell_segment)
    # the sets of the mesh file, independently of the model's bookkeeping
    raw = meshio.read(Path(model.source).parent / "box.vtu")
    np.testing.assert_array_equal(seg == 0, raw.cell_data["root"][0] == 1)
    np.testing.assert_array_equal(seg == 1, raw.cell_data["middle"][0] == 1)
    assert np.sum(seg == -1) == 24  # x > 0.2 m: the fixed remainder
    for name, values in (("alpha", ALPHA), ("gamma", GAMMA)):
        data = back.cell_data[name][0]
        np.testing.assert_array_equal(data[seg >= 0], values[seg[seg >= 0]])
        assert np.all(np.isnan(data[seg < 0]))


def test_without_gamma_there_is_no_gamma_field(model, tmp_path):
    back = _round_trip(model_vtu(model, ALPHA, None, 2), tmp_path)
    assert set(back.cell_data) == {"segment", "alpha"} and len(back.point_data) == 2


def test_modes_are_those_of_the_updated_model(model, tmp_path):
    back = _round_trip(model_vtu(model, ALPHA, GAMMA, N_MODES), tmp_path)
    modes = sorted((parse_mode_field(name), field) for name, field in back.point_data.items())
    assert [k for (k, _), _ in modes] == list(range(1, N_MODES + 1))
    freqs = np.array([f for (_, f), _ in modes])
    K = model.stiffness(ALPHA).toarray()
    M = model.mass(GAMMA).toarray()
    w2, vecs = scipy.linalg.eigh(K, M, subset_by_index=[0, N_MODES - 1])
    np.testing.assert_allclose(freqs, np.sqrt(w2) / (2 * np.pi), rtol=FREQ_RTOL)
    Ks, Ms = model.stiffness(ALPHA), model.mass(GAMMA)
    fixed = np.setdiff1d(np.arange(model.n_total_dofs), model.free_dofs)
    for k, ((_, f), field) in enumerate(modes):
        assert field.shape == (model.mesh.n_nodes, 3)
        full = field.reshape(-1)
        assert np.all(full[fixed] == 0.0)  # supported DOFs do not move
        phi = full[model.free_dofs]
        w2k = (2 * np.pi * f) ** 2
        residual = np.linalg.norm(Ks @ phi - w2k * (Ms @ phi)) / np.linalg.norm(Ks @ phi)
        assert residual <= RESIDUAL_RTOL  # the name's 10 digits of f add 1e-9 through w^2
        assert phi @ (Ms @ phi) == pytest.approx(1.0, rel=1e-10)  # mass-normalised
        assert abs(phi @ M @ vecs[:, k]) == pytest.approx(1.0, rel=1e-8)  # the same mode as the dense solve


def test_a_matrices_model_has_no_cells_to_write():
    from flows.config import REPO

    model = read_model(REPO / "data" / "examples" / "cantilever_matrices" / "model.toml")
    with pytest.raises(ValueError, match="matrices"):
        model_vtu(model, np.zeros(model.n_segments))


def test_wrong_number_of_factors_is_refused(model):
    with pytest.raises(ValueError, match="gamma must have 2 entries"):
        model_vtu(model, ALPHA, [0.1, 0.2, 0.3], 1)


@pytest.mark.parametrize("max_bandwidth", [0, 10**9])
def test_modes_by_sparse_cholesky_and_by_superlu_equal_the_dense_solve(model, monkeypatch, max_bandwidth):
    """A wide-band K (any gmsh mesh) is factored by PARDISO for the modes, a banded one by SuperLU."""
    import fe_core.solvers.frf
    from fe_core.solvers.modal import eigenmodes

    calls = []
    real = fe_core.solvers.frf.spd_solver
    monkeypatch.setattr(fe_core.solvers.frf, "MAX_BANDWIDTH", max_bandwidth)
    monkeypatch.setattr(fe_core.solvers.frf, "spd_solver", lambda A: calls.append(A.shape) or real(A))
    K, M = model.stiffness(ALPHA), model.mass(GAMMA)
    freqs, vecs = eigenmodes(K, M, N_MODES)
    assert len(calls) == (1 if max_bandwidth == 0 else 0)
    w2 = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True, subset_by_index=[0, N_MODES - 1])
    np.testing.assert_allclose(freqs, np.sqrt(w2) / (2 * np.pi), rtol=FREQ_RTOL)
    residual = np.linalg.norm(K @ vecs - (M @ vecs) * (2 * np.pi * freqs) ** 2, axis=0)
    assert np.all(residual <= RESIDUAL_RTOL * np.linalg.norm(K @ vecs, axis=0))
