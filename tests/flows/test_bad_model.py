"""Bad model files to ``python -m flows.update --model``: exit 2, the file and key named, nothing written.

Each case starts from a working model (the benchmark's ``data/benchmark/model.toml``
or the scikit-fem matrices example), copied into ``tmp_path``, and breaks one thing:
the TOML text, the mesh or a matrix file. The command runs in-process
(``flows.update.main``); every refusal comes before any Prefect run or file.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import meshio
import numpy as np
import pytest
import scipy.io

from flows import update
from flows.config import REPO

BENCH = REPO / "data" / "benchmark"
MATRICES = REPO / "data" / "examples" / "cantilever_matrices"
BENCH_TOML = (BENCH / "model.toml").read_text()
MATRICES_TOML = (MATRICES / "model.toml").read_text()
N_DOFS = len((MATRICES / "dofs.csv").read_text().splitlines()) - 1


def _mesh_case(tmp: Path, edit_mesh=None, toml: str = BENCH_TOML) -> Path:
    """The benchmark model in ``tmp``; ``edit_mesh(mesh)`` may change the meshio mesh first."""
    if edit_mesh is None:
        shutil.copy(BENCH / "three_plate.inp", tmp / "three_plate.inp")
    else:
        mesh = meshio.read(BENCH / "three_plate.inp")
        edit_mesh(mesh)
        meshio.write(tmp / "three_plate.inp", mesh, file_format="abaqus")
    (tmp / "model.toml").write_text(toml)
    return tmp / "model.toml"


def _matrices_case(tmp: Path, edit=None, toml: str = MATRICES_TOML) -> Path:
    for f in MATRICES.iterdir():
        shutil.copy(f, tmp / f.name)
    if edit is not None:
        edit(tmp)
    (tmp / "model.toml").write_text(toml)
    return tmp / "model.toml"


def _invert_cell(mesh, k=5):
    cells = mesh.cells[0].data
    cells[k] = cells[k][[4, 5, 6, 7, 0, 1, 2, 3]]  # top and bottom faces swapped: negative Jacobian


def _flatten_cell(mesh, k=7):
    cells = mesh.cells[0].data
    cells[k, 4:] = cells[k, :4]  # the top face on the bottom one: zero volume


def _wedges(mesh):
    cells = mesh.cells[0].data
    mesh.cells[0] = meshio.CellBlock("wedge", cells[:, [0, 1, 2, 4, 5, 6]])


def _millimetres(mesh):
    mesh.points *= 1000.0


def _points_in_mm(toml: str) -> str:
    """The model text with every point in mm (the mesh in mm, the materials left in SI)."""
    import re

    def scale(m):
        return "point = [" + ", ".join(f"{1000 * float(v):.12g}" for v in m.group(1).split(",")) + "]"

    return re.sub(r"point = \[([^\]]*)\]", scale, toml).replace("point_tolerance = 1e-6", "point_tolerance = 1e-3")


def _matrix_edit(name, how):
    def edit(tmp):
        A = scipy.io.mmread(str(tmp / name)).tocsr()
        if how == "asymmetric":
            A = A.tolil()
            A[3, 10] = A[3, 10] + 1e3 * abs(A).max()
        elif how == "negative":
            A = -A
        scipy.io.mmwrite(str(tmp / name), A.tocsr(), precision=17)
    return edit


def _node_row(tmp, row="17,0.64,zero,0.05"):
    lines = (tmp / "nodes.csv").read_text().splitlines()
    lines[5] = row   # line 6 of the file
    (tmp / "nodes.csv").write_text("\n".join(lines) + "\n")


def _drop_dof_rows(tmp):
    lines = (tmp / "dofs.csv").read_text().splitlines()
    (tmp / "dofs.csv").write_text("\n".join(lines[:-3]) + "\n")


SENSOR1 = "point = [0.02875, 0.02, 0.01]"
CLAMPED_POINT = "point = [0.0, 0.0, 0.01]"
BENCH_M = str(BENCH / "measured.csv")
MATRICES_M = str(MATRICES / "measured.csv")

# (id, builder(tmp) -> model path, measured, message parts); "{model}" is the model file.
CASES = [
    ("unknown cell set", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('"segment3"', '"segment9"')), BENCH_M,
     ["{model}", "key 'segments[2].set'", "no cell set 'segment9'"]),
    ("unknown node set", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('nodes = "clamped"', 'nodes = "ends"')),
     BENCH_M, ["{model}", "key 'supports[0].nodes'", "no node set 'ends'", "clamped"]),
    ("missing segments", lambda t: _mesh_case(t, toml="\n".join(
        line for line in BENCH_TOML.splitlines() if "segment" not in line)), BENCH_M,
     ["{model}", "key 'segments'", "is missing"]),
    ("unsupported element type", lambda t: _mesh_case(t, _wedges), BENCH_M,
     ["{model}", "key 'mesh'", "unsupported element type 'wedge'", "hexahedron"]),
    ("inverted element", lambda t: _mesh_case(t, _invert_cell), BENCH_M,
     ["{model}", "key 'mesh'", "cell 5", "non-positive Jacobian"]),
    ("degenerate element", lambda t: _mesh_case(t, _flatten_cell), BENCH_M,
     ["{model}", "key 'mesh'", "cell 7", "non-positive Jacobian"]),
    ("overlapping segments", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('set = "segment2"', 'set = "plate1"')),
     BENCH_M, ["{model}", "key 'segments[1].set'", "segments overlap", "'segment1'"]),
    ("sensor on a fixed DOF", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(SENSOR1, CLAMPED_POINT, 1)), BENCH_M,
     ["{model}", "key 'sensors[0]'", "fixed by a support"]),
    ("excitation on a fixed DOF", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        "{ " + SENSOR1, "{ " + CLAMPED_POINT)), BENCH_M, ["{model}", "key 'excitations[0].dofs[0]'", "fixed by a support"]),
    ("sensor beyond the tolerance", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        SENSOR1, "point = [0.02875, 0.02, 0.0105]", 1)), BENCH_M,
     ["{model}", "key 'sensors[0].point'", "0.0005", "beyond point_tolerance"]),
    ("unrestrained structure", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('fix = ["x", "y", "z"]', 'fix = ["z"]')),
     BENCH_M, ["{model}", "key 'supports'", "3 rigid-body mode(s)", "translation x", "translation y",
               "rotation about z"]),
    ("no supports at all", lambda t: _mesh_case(t, toml=BENCH_TOML.replace("[[supports]]", "[[nosupports]]")), BENCH_M,
     ["{model}", "unknown key"]),
    ("matrix not symmetric", lambda t: _matrices_case(t, _matrix_edit("K_seg2.mtx", "asymmetric")), MATRICES_M,
     ["{model}", "key 'segments[1].stiffness'", "K_seg2.mtx is not symmetric"]),
    ("matrix not positive semidefinite", lambda t: _matrices_case(t, _matrix_edit("M_seg3.mtx", "negative")),
     MATRICES_M, ["{model}", "key 'segments[2].mass'", "not positive semidefinite"]),
    ("bad row of the node table", lambda t: _matrices_case(t, _node_row), MATRICES_M,
     ["{model}", "key 'matrices.nodes'", "nodes.csv: line 6", "'17,0.64,zero,0.05'"]),
    ("node without coordinates", lambda t: _matrices_case(t, lambda tmp: _node_row(tmp, "9999,0,0,0")), MATRICES_M,
     ["{model}", "key 'matrices.nodes'", "nodes.csv: no coordinates for 1 node(s)", "node(s) [4]"]),
    ("sizes do not match the DOF table", lambda t: _matrices_case(t, _drop_dof_rows), MATRICES_M,
     ["{model}", "key 'segments[0].stiffness'", f"{N_DOFS} x {N_DOFS}", f"{N_DOFS - 3} rows"]),
    ("unrestrained matrices", lambda t: _matrices_case(t, toml=MATRICES_TOML.replace("[[supports]]\nnodes",
                                                                                     "#[[supports]]\n#nodes").replace(
        '\nfix = ["x", "y", "z"]', "\n#fix")), MATRICES_M,
     ["{model}", "key 'supports'", "6 rigid-body mode(s) or mechanism(s)", "lowest natural frequencies"]),
    ("mesh in mm with SI materials", lambda t: _mesh_case(t, _millimetres, _points_in_mm(BENCH_TOML)), BENCH_M,
     ["{model}", "far outside the measured band 106-295 Hz", "mm-t-s"]),
    ("missing key", lambda t: _mesh_case(t, toml=BENCH_TOML.replace("rho = 7850.0", "")), BENCH_M,
     ["{model}", "key 'materials[0].rho'", "is missing"]),
    ("wrong type", lambda t: _mesh_case(t, toml=BENCH_TOML.replace("nu = 0.3", 'nu = "0.3"')), BENCH_M,
     ["{model}", "key 'materials[0].nu'", "must be number", "str '0.3'"]),
    ("unknown direction", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('direction = "z"', 'direction = "w"', 1)),
     BENCH_M, ["{model}", "key 'sensors[0].direction'", "'w'"]),
    ("not TOML", lambda t: _mesh_case(t, toml="units = = 3\n"), BENCH_M, ["{model}", "not valid TOML"]),
    ("test direction without a test node", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        "test_node = 2  #", 'test_direction = "+z"  #', 1)), BENCH_M,
     ["{model}", "key 'sensors[1].test_direction'", "needs test_node"]),
    ("test node 0", lambda t: _mesh_case(t, toml=BENCH_TOML.replace("test_node = 3  #", "test_node = 0  #", 1)),
     BENCH_M, ["{model}", "key 'sensors[2].test_node'", ">= 1"]),
    ("one test DOF for two sensors", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        "test_node = 4  #", "test_node = 3  #", 1)), BENCH_M,
     ["{model}", "key 'sensors[3].test_node'", "test node 3 direction z is also that of sensors[2]"]),
    ("unknown test direction", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        "test_node = 5\n", 'test_node = 5\ntest_direction = "up"\n', 1)), BENCH_M,
     ["{model}", "key 'excitations[1].test_direction'", "'up'"]),
    ("vector direction without a test direction", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        'direction = "z"\ntest_node = 1', 'direction = [0.0, 0.6, 0.8]\ntest_node = 1', 1)), BENCH_M,
     ["{model}", "key 'sensors[0].test_direction'", "not x, y or z"]),
    ("two excitations of one name", lambda t: _mesh_case(t, toml=BENCH_TOML.replace('name = "hammer"',
                                                                                    'name = "combined"')),
     BENCH_M, ["{model}", "key 'excitations[1].name'", "used twice"]),
    ("missing mesh file", lambda t: _mesh_case(t, toml=BENCH_TOML.replace("three_plate.inp", "nowhere.msh")), BENCH_M,
     ["{model}", "key 'mesh'", "nowhere.msh", "does not exist"]),
    ("mass factor without the stiffness factor", lambda t: _matrices_case(t, toml=MATRICES_TOML.replace(
        'name = "seg2"', 'name = "seg2"\nupdate = ["mass"]')), MATRICES_M,
     ["{model}", "key 'segments[1].update'", "'seg2'", "always updated"]),
    ("mass bounds of a mass not updated", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        'set = "segment2"', 'set = "segment2"\nmass_bounds = [-0.2, 0.2]')), BENCH_M,
     ["{model}", "key 'segments[1].mass_bounds'", "not updated", 'update = ["stiffness", "mass"]']),
    ("mass bounds outside the domain", lambda t: _mesh_case(t, toml=BENCH_TOML.replace(
        'set = "segment2"', 'set = "segment2"\nupdate = ["stiffness", "mass"]\nmass_bounds = [-1.5, 0.2]')),
     BENCH_M, ["{model}", "key 'segments[1].mass_bounds'", "gamma > -1 keeps the mass positive"]),
]


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()} if root.exists() else {}


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_model_exits_2_names_file_and_key_writes_nothing(case, tmp_path, capsys):
    _, build, measured, needles = case
    model_dir = tmp_path / "model"
    model_dir.mkdir()
    model = build(model_dir)
    runs = tmp_path / "runs"
    code = update.main(["--model", str(model), "--measured", measured, "--runs-dir", str(runs), "--run-id", "new"])
    err = capsys.readouterr().err
    assert code == 2, err
    for needle in needles:
        assert needle.format(model=model) in err, err
    assert "Traceback" not in err
    assert not (runs / "new").exists()


def test_closing_the_loop_on_a_model_with_mass_factors_is_refused_before_any_work(tmp_path, capsys):
    """The closure refits alpha only: a model file that updates a mass factor cannot be closed (flows.diagnose
    refuses such a finished run too); said before the update, not after it."""
    model = _matrices_case(tmp_path, toml=MATRICES_TOML.replace('name = "seg2"',
                                                                'name = "seg2"\nupdate = ["stiffness", "mass"]'))
    runs = tmp_path / "runs"
    code = update.main(["--model", str(model), "--measured", MATRICES_M, "--runs-dir", str(runs), "--run-id", "new",
                        "--close-loop"])
    err = capsys.readouterr().err
    assert code == 2 and "--close-loop" in err and "gamma_2" in err and "alpha only" in err, err
    assert not (runs / "new").exists()


def test_an_unknown_model_path_is_refused(tmp_path, capsys):
    code = update.main(["--model", str(tmp_path / "none.toml"), "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2
    assert "command line: key 'model'" in err and "none.toml" in err and "does not exist" in err


def test_the_degenerate_case_really_has_zero_volume():
    """The flattened cell of the 'degenerate element' case: all eight corners on one plane."""
    mesh = meshio.read(BENCH / "three_plate.inp")
    _flatten_cell(mesh)
    corners = mesh.points[mesh.cells[0].data[7]]
    assert np.ptp(corners[:, 2]) == 0.0


def test_a_large_models_band_check_refuses_a_mesh_in_mm_too(tmp_path, capsys, monkeypatch):
    """A large model's band check takes its frequencies to ARPACK's tol = BAND_TOL (preflight.check_band);
    forced here on the benchmark's mesh in mm (the threshold lowered), it still refuses the units mix-up."""
    import tasks.fe_runs

    monkeypatch.setattr(tasks.fe_runs, "LARGE_DOFS", 0)
    model_dir = tmp_path / "model"
    model_dir.mkdir()
    model = _mesh_case(model_dir, _millimetres, _points_in_mm(BENCH_TOML))
    runs = tmp_path / "runs"
    code = update.main(["--model", str(model), "--measured", BENCH_M, "--runs-dir", str(runs), "--run-id", "new"])
    err = capsys.readouterr().err
    assert code == 2 and "far outside the measured band 106-295 Hz" in err and "mm-t-s" in err, err
    assert not (runs / "new").exists()
