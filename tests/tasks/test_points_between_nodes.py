"""A mesh model whose sensors are read between nodes (``point_placement = "interpolate"``): what needs a
sensor's node gets its nearest node (sensor mass, the report's arrows), and the modal shapes figure reads
the model through the output vectors."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import meshio
import numpy as np

from fe_core.io import read_model
from fe_core.tet_mesh import box_tets

POINTS = [[0.2213, 0.0317, 0.04], [0.0871, 0.0412, 0.0263], [0.1502, 0.0089, 0.04]]


def _model(tmp_path: Path):
    nodes, cells = box_tets((0.3, 0.06, 0.04), (6, 2, 2), order=2)
    meshio.write(tmp_path / "box.vtu", meshio.Mesh(nodes, [("tetra10", cells)], point_data={
        "clamped": np.isclose(nodes[:, 0], 0.0).astype(np.int32)}, cell_data={"all": [np.ones(len(cells), np.int32)]}))
    text = ['point_placement = "interpolate"', 'mesh = "box.vtu"', "[[materials]]", "E = 7e10", "nu = 0.33",
            "rho = 2700.0", "[[segments]]", 'set = "all"', "[[supports]]", 'nodes = "clamped"']
    for k, p in enumerate(POINTS):
        text += ["[[sensors]]", f'name = "s{k}"', f"point = {p}", 'direction = "z"', f"test_node = {k + 1}"]
    text += ["[[excitations]]", f"point = {POINTS[0]}", 'direction = "z"', ""]
    (tmp_path / "m.toml").write_text("\n".join(text))
    model = read_model(tmp_path / "m.toml")
    nearest = [int(np.argmin(np.linalg.norm(nodes - p, axis=1))) for p in POINTS]
    return model, nearest


def test_sensor_mass_and_report_arrows_use_the_nearest_node(tmp_path):
    from fe_core.closure.effects.masses import SensorMass
    from tasks.report.mesh import MeshView, _at_node, _entry_arrows

    model, nearest = _model(tmp_path)
    assert model.sensor_nodes.tolist() == nearest
    assert SensorMass(model).nodes.tolist() == nearest
    view = MeshView(model)
    for j, node in enumerate(nearest):
        arrows = view.arrows(model, model.outputs.tocsc()[:, j])
        assert len(arrows.nodes) > 1                       # the element's nodes carry the reading
        one = _at_node(model, arrows, node)
        assert one.nodes.tolist() == [node] and np.allclose(one.directions, [[0.0, 0.0, 1.0]], atol=1e-12)
    assert model.excitation_nodes == {"excitation 1": [(nearest[0], [0.0, 0.0, 1.0])]}
    hammer = _entry_arrows(model, model.excitation_nodes[model.excitation_name])
    assert hammer.nodes.tolist() == [nearest[0]] and hammer.directions.tolist() == [[0.0, 0.0, 1.0]]
    assert len(view.arrows(model, model.load).nodes) > 1


def test_the_modal_shapes_figure_reads_through_the_output_vectors(tmp_path):
    from tasks import modal

    model, _ = _model(tmp_path)
    theta = np.zeros(model.n_parameters)
    freqs, shapes, _ = model.modes(*model.factors(theta)[:1], 3)
    u = shapes[0].reshape(-1)[model.free_dofs]
    data = SimpleNamespace(outputs=model.outputs.tocsc(),
                           modes=SimpleNamespace(names=["T1"], shapes=np.asarray(model.outputs.T @ u)[None]))
    result = {"model_frequencies_hz": list(freqs),
              "pairs": [{"test": "T1", "model": "mode 1", "f_test_hz": freqs[0], "f_model_hz": freqs[0],
                         "mac": 1.0}]}
    path = modal.shapes_figure(data, model, theta, result, tmp_path / "shapes.png")
    assert path.exists() and path.stat().st_size > 1000
