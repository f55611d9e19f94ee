"""``point_placement = "interpolate"`` in a model file: sensors and the hammer between nodes read through the
element's shape functions (scikit-fem's probes as the reference), the default unchanged, reciprocity, and the
refusals naming the key."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

from fe_core.io import ModelFileError, read_model
from fe_core.mesh import Block, mesh_blocks
from fe_core.tet_mesh import box_tets

SIZE = (0.3, 0.06, 0.04)
FREQS = np.array([300.0, 1700.0, 4100.0])
P1, P2 = [0.2213, 0.0317, 0.0129], [0.0871, 0.0412, 0.0263]   # interior, on no node


def _write_box(path: Path, cell_type: str = "tetra10") -> tuple[np.ndarray, np.ndarray]:
    """The box in tet10 (or hex8) cells, two cell sets split at x = 0.15, clamped at x = 0, as .vtu."""
    if cell_type == "hexahedron":
        mesh = mesh_blocks([Block(np.linspace(0, 0.15, 4), np.linspace(0, 0.06, 3), np.linspace(0, 0.04, 3), "a"),
                            Block(np.linspace(0.15, 0.3, 4), np.linspace(0, 0.06, 3), np.linspace(0, 0.04, 3), "b")])
        nodes, cells = mesh.nodes, mesh.cells
    else:
        nodes, cells = box_tets(SIZE, (6, 2, 2), order=2)
    left = nodes[cells].mean(axis=1)[:, 0] < 0.15
    out = meshio.Mesh(nodes, [(cell_type, cells)],
                      cell_data={"a": [left.astype(np.int32)], "b": [(~left).astype(np.int32)]},
                      point_data={"clamped": np.isclose(nodes[:, 0], 0.0).astype(np.int32)})
    meshio.write(path, out)
    return nodes, cells


def _toml(mesh: str, sensor, hammer, placement: str | None = "interpolate", sensor_dir="[0.0, 0.6, 0.8]",
          hammer_dir='"z"', extra: str = "") -> str:
    top = [f'point_placement = "{placement}"'] if placement else []
    return "\n".join(top + [extra, f'mesh = "{mesh}"', "[damping]", "a = 4.0", "b = 1e-6",
                            "[[materials]]", "E = 7e10", "nu = 0.33", "rho = 2700.0",
                            '[[segments]]', 'set = "a"', '[[segments]]', 'set = "b"',
                            '[[supports]]', 'nodes = "clamped"',
                            '[[sensors]]', 'name = "s"', f"point = {list(sensor)}", f"direction = {sensor_dir}",
                            '[[excitations]]', 'name = "hammer"', f"point = {list(hammer)}",
                            f"direction = {hammer_dir}", ""])


def _model(tmp_path: Path, name: str, text: str):
    (tmp_path / name).write_text(text)
    return read_model(tmp_path / name)


def _full(model, vector) -> np.ndarray:
    """A free-DOF vector on all DOFs, shape (n_nodes, 3)."""
    v = np.zeros(model.n_total_dofs)
    v[model.free_dofs] = np.asarray(vector.toarray() if hasattr(vector, "toarray") else vector).ravel()
    return v.reshape(-1, 3)


def test_tet10_sensor_and_hammer_rows_are_scikit_fems_probes(tmp_path):
    from skfem import Basis, ElementTetP2, MeshTet

    nodes, cells = _write_box(tmp_path / "box.vtu")
    model = _model(tmp_path, "m.toml", _toml("box.vtu", P1, P2))
    # scikit-fem on the corner mesh, P2: its dofs are our nodes (matched by position)
    corners = np.unique(cells[:, :4])
    index = np.full(len(nodes), -1)
    index[corners] = np.arange(corners.size)
    basis = Basis(MeshTet(nodes[corners].T.copy(), index[cells[:, :4]].T.copy()), ElementTetP2())
    ours = [int(np.argmin(np.linalg.norm(nodes - x, axis=1))) for x in basis.doflocs.T]
    assert np.allclose(nodes[ours], basis.doflocs.T, atol=1e-14)
    for point, vector, direction in ((P1, model.outputs[:, 0], np.array([0.0, 0.6, 0.8])),
                                     (P2, model.load, np.array([0.0, 0.0, 1.0]))):
        probe = np.zeros(len(nodes))
        probe[ours] = basis.probes(np.array(point)[:, None]).toarray()[0]
        expected = probe[:, None] * direction
        expected[np.isclose(nodes[:, 0], 0.0)] = 0.0            # clamped DOFs carry nothing
        np.testing.assert_allclose(_full(model, vector), expected, rtol=0, atol=1e-10)
    assert model.sensor_nodes.tolist() == [int(np.argmin(np.linalg.norm(nodes - P1, axis=1)))]
    assert any("between nodes: element" in p and "from nearest node" in p for p in model.placements)
    with pytest.raises(ValueError, match="combines several DOFs"):   # one-DOF views refuse it (not on the
        _ = model.sensor_dofs                                        # update's path: it reads `outputs`)


def test_the_default_and_nearest_are_todays_placement_and_a_point_at_a_node_reads_that_node(tmp_path):
    nodes, _ = _write_box(tmp_path / "box.vtu")
    node = 2 * len(nodes) // 3
    at_node = nodes[node].tolist()
    default = _model(tmp_path, "d.toml", _toml("box.vtu", P1, P2, placement=None, extra="point_tolerance = 0.02"))
    nearest = _model(tmp_path, "n.toml", _toml("box.vtu", P1, P2, placement="nearest",
                                               extra="point_tolerance = 0.02"))
    for m in (default, nearest):   # one node, weight 1: the nearest node's DOFs along the direction
        L = _full(m, m.outputs[:, 0])
        n1 = int(np.argmin(np.linalg.norm(nodes - P1, axis=1)))
        assert np.flatnonzero(np.abs(L).sum(axis=1)).tolist() == [n1] and np.array_equal(L[n1], [0.0, 0.6, 0.8])
        assert m.sensor_nodes is None
    assert (default.outputs != nearest.outputs).nnz == 0 and np.array_equal(default.load, nearest.load)
    assert np.array_equal(default.excitation_loads, nearest.excitation_loads)
    assert default.placements == nearest.placements
    near = _model(tmp_path, "a.toml", _toml("box.vtu", at_node, at_node, placement="nearest"))
    inter = _model(tmp_path, "b.toml", _toml("box.vtu", at_node, at_node))
    assert (near.outputs != inter.outputs).nnz == 0 and np.array_equal(near.load, inter.load)
    assert inter.outputs.nnz == 2 and f"at node {node}" in inter.placements[0]


def test_reciprocity_between_two_interior_points(tmp_path):
    _write_box(tmp_path / "box.vtu")
    d1, d2 = "[0.0, 0.6, 0.8]", "[1.0, 0.0, 0.0]"
    ij = _model(tmp_path, "ij.toml", _toml("box.vtu", P1, P2, sensor_dir=d1, hammer_dir=d2))
    ji = _model(tmp_path, "ji.toml", _toml("box.vtu", P2, P1, sensor_dir=d2, hammer_dir=d1))
    alpha = [0.2, -0.1]
    Zij = ij.frf(alpha, FREQS, method="direct")[:, 0]
    Zji = ji.frf(alpha, FREQS, method="direct")[:, 0]
    np.testing.assert_allclose(Zij, Zji, rtol=1e-10, atol=0)
    # the update's default solve takes the general output and load vectors as they are
    np.testing.assert_allclose(ij.frf(alpha, FREQS)[:, 0], Zij, rtol=1e-8, atol=0)
    nearest = _model(tmp_path, "n.toml", _toml("box.vtu", P1, P2, placement="nearest", sensor_dir=d1,
                                               hammer_dir=d2, extra="point_tolerance = 0.02"))
    assert np.max(np.abs(nearest.frf(alpha, FREQS, method="direct")[:, 0] / Zij - 1)) > 1e-3   # not the node's


def test_hex8_rows_map_back_to_the_point_and_skip_clamped_dofs(tmp_path):
    nodes, _ = _write_box(tmp_path / "hex.vtu", "hexahedron")
    near_clamp = [0.021, 0.0333, 0.0127]            # in a cell with clamped nodes at x = 0
    model = _model(tmp_path, "h.toml", _toml("hex.vtu", P1, near_clamp, sensor_dir='"x"', hammer_dir='"y"'))
    for point, vector, c in ((P1, model.outputs[:, 0], 0), (near_clamp, model.load, 1)):
        W = _full(model, vector)
        w = W[:, c]
        assert np.all(W[:, [k for k in range(3) if k != c]] == 0.0)
        free = ~np.isclose(nodes[:, 0], 0.0)
        assert np.all(w[~free] == 0.0)
        if point is P1:     # the trilinear map: the weights read the point's coordinates back
            np.testing.assert_allclose(w @ nodes, point, rtol=0, atol=1e-12)
            assert w.sum() == pytest.approx(1.0, abs=1e-14)
        else:               # the clamped nodes' shares are dropped, the rest kept as they are
            assert 0.0 < w.sum() < 1.0 and np.count_nonzero(w) == 4


def _error(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    with pytest.raises(ModelFileError) as err:
        read_model(tmp_path / name)
    return str(err.value)


def test_refusals_name_the_key(tmp_path):
    _write_box(tmp_path / "box.vtu")
    far = [0.35, 0.03, 0.02]                        # 5 cm beyond the end x = 0.3
    msg = _error(tmp_path, "far.toml", _toml("box.vtu", P1, far))
    assert "key 'excitations[0].point'" in msg and "outside the mesh" in msg and "point_tolerance" in msg
    msg = _error(tmp_path, "far2.toml", _toml("box.vtu", far, P1, extra="point_tolerance = 0.01"))
    assert "key 'sensors[0].point'" in msg and "outside the mesh" in msg
    # a little outside (1 mm, within the default 1 % of 0.3 m): onto the surface, and said so
    model = _model(tmp_path, "near.toml", _toml("box.vtu", [0.301, 0.03, 0.02], P1))
    assert "outside the mesh" in model.placements[0]
    msg = _error(tmp_path, "bad.toml", _toml("box.vtu", P1, P2, placement="shape_functions"))
    assert "key 'point_placement'" in msg and "unknown value 'shape_functions'" in msg
    clamped = _error(tmp_path, "c.toml", _toml("box.vtu", [0.0, 0.0311, 0.0172], P1))
    assert "key 'sensors[0]'" in clamped and "fixed by a support" in clamped
    # models without elements of their own: matrices and a CalculiX deck
    (tmp_path / "dofs.csv").write_text("node,direction\n1,1\n")
    msg = _error(tmp_path, "mat.toml", 'point_placement = "interpolate"\n[matrices]\ndofs = "dofs.csv"\n')
    assert "key 'point_placement'" in msg and "mesh model" in msg
    (tmp_path / "deck.inp").write_text("*NODE\n1, 0., 0., 0.\n")
    msg = _error(tmp_path, "deck.toml", 'point_placement = "interpolate"\nsolver = "calculix"\ndeck = "deck.inp"\n')
    assert "key 'point_placement'" in msg and "mesh model" in msg
