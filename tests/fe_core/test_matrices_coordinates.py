"""A matrices model's optional node table (``[matrices] nodes = "nodes.csv"``, header ``node,x,y,z``): read into the
model, used by the closure to place nodal effects and to measure how far their evidence spreads; bad rows refused
naming the file and the line (the command's exit 2 for them: tests/flows/test_bad_model.py).

References: the cantilever example is scikit-fem's tensor-product mesh of a 1.0 x 0.08 x 0.05 m beam
(``benchmarks.make.matrix_example``); its sensors sit on the top edge at x = 0.2 ... 1.0 m (the model file's
names), and the own cases' truth file records scikit-fem's coordinates of their nodes.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from fe_core.closure.effects import PointMass
from fe_core.closure.identify import LOCATION_SHARE, located, spread_mm
from fe_core.io import ModelFileError, read_model
from fe_core.io.matrices import MatrixFileError, read_node_table
from flows.config import REPO

MATRICES = REPO / "data" / "examples" / "cantilever_matrices"
LENGTH, WIDTH, HEIGHT = 1.0, 0.08, 0.05


@pytest.fixture(scope="module")
def cantilever():
    return read_model(MATRICES / "model.toml")


def test_the_cantilever_reads_scikit_fems_coordinates(cantilever):
    model = cantilever
    nodes = np.unique(model.dof_table[:, 0])
    xyz = np.array([model.node_position(n) for n in nodes])
    # Every node on the 26 x 3 x 3 grid, each grid point once.
    grid = {(round(x, 9), round(y, 9), round(z, 9)) for x in np.linspace(0, LENGTH, 26)
            for y in np.linspace(0, WIDTH, 3) for z in np.linspace(0, HEIGHT, 3)}
    assert {tuple(np.round(p, 9)) for p in xyz} == grid and len(xyz) == len(grid)
    assert model.size_m == pytest.approx(np.sqrt(LENGTH**2 + WIDTH**2 + HEIGHT**2), rel=1e-12)
    # The truth file's nodes (scikit-fem's p of the own cases on this model).
    truth = json.loads((REPO / "data" / "cases" / "own_structures" / "truth.json").read_text())
    for t in truth["cases"].values():
        if t["structure"] == "cantilever":
            np.testing.assert_allclose(model.node_position(t["node"]), t["xyz_m"], atol=1e-12)
    # The sensors: u_y on the top edge (y = 0.08, z = 0.05) at the x their names give.
    sensor_nodes = [int(line.split("=")[1]) for line in (MATRICES / "model.toml").read_text().splitlines()
                    if line.startswith("node = ")][:5]
    for name, node in zip(model.sensor_names, sensor_nodes):
        x = float(name.split("x = ")[1].split(" m")[0])
        np.testing.assert_allclose(model.node_position(node), [x, WIDTH, HEIGHT], atol=1e-12)
    assert model.node_position(10_000) is None


def test_nodal_effects_are_placed_and_their_spread_measured(cantilever, tmp_path):
    pm = PointMass(cantilever, [42, 45, 46, 47, 49])   # (0.56, 0, 0), (0.6, 0, 0), (0.6, .04, 0), (0.6, .08, 0), (0.64, .04, 0)
    assert pm.describe("node 46") == {"node": 46, "x_m": 0.6, "y_m": 0.04, "z_m": 0.0}
    limit_mm = 1e3 * LOCATION_SHARE * cantilever.size_m          # 50.2 mm
    near = [("node 46", 0.5), ("node 45", 0.2), ("node 47", 0.2), ("node 49", 0.1)]   # all 40 mm away
    far = near[:3] + [("node 42", 0.1)]                                               # 56.6 mm
    assert spread_mm(pm, "node 46", near) == pytest.approx(40.0) and 40.0 < limit_mm
    assert spread_mm(pm, "node 46", far) == pytest.approx(1e3 * np.hypot(0.04, 0.04)) and 56.5 > limit_mm
    assert located(cantilever, pm, "node 46", near) and not located(cantilever, pm, "node 46", far)
    # Without the node table the same model has no positions: a spread over several nodes is not located.
    for f in MATRICES.iterdir():
        shutil.copy(f, tmp_path / f.name)
    text = (MATRICES / "model.toml").read_text()
    kept = [line for line in text.splitlines() if not line.startswith('nodes = "nodes.csv"')]
    (tmp_path / "model.toml").write_text("\n".join(kept))
    bare = read_model(tmp_path / "model.toml")
    pm0 = PointMass(bare, [45, 46])
    assert bare.size_m is None and pm0.position("node 46") is None and pm0.describe("node 46") == {"node": 46}
    assert not located(bare, pm0, "node 46", [("node 46", 0.6), ("node 45", 0.4)])
    assert located(bare, pm0, "node 46", [("node 46", 1.0)])


@pytest.mark.parametrize("text, needles", [
    ("node,x,y\n0,0,0\n", ["header 'node,x,y,z'"]),
    ("node,x,y,z\n0,0,0,0\n1,0.1,0,zero\n", ["line 3", "'1,0.1,0,zero'"]),
    ("node,x,y,z\n0,0,0,0\n1,0.1,0\n", ["line 3", "expected 'node,x,y,z'"]),
    ("node,x,y,z\n0,0,0,0\n1.5,0,0,0\n", ["line 3"]),
    ("node,x,y,z\n0,0,0,0\n1,nan,0,0\n", ["line 3", "non-finite"]),
    ("node,x,y,z\n0,0,0,0\n1,0,0,1\n0,1,0,0\n", ["line 4", "node 0 is listed again (first on line 2)"]),
])
def test_bad_node_tables_are_refused_naming_the_file_and_line(tmp_path, text, needles):
    path = tmp_path / "nodes.csv"
    path.write_text(text)
    with pytest.raises(MatrixFileError) as err:
        read_node_table(path)
    for needle in [str(path)] + needles:
        assert needle in str(err.value)


def test_a_node_without_coordinates_is_refused_naming_it(tmp_path):
    for f in MATRICES.iterdir():
        shutil.copy(f, tmp_path / f.name)
    lines = (MATRICES / "nodes.csv").read_text().splitlines()
    (tmp_path / "nodes.csv").write_text("\n".join(line for line in lines if not line.startswith("17,")) + "\n")
    with pytest.raises(ModelFileError) as err:
        read_model(tmp_path / "model.toml")
    msg = str(err.value)
    assert "key 'matrices.nodes'" in msg and "nodes.csv" in msg and "node(s) [17]" in msg and "dofs.csv" in msg
