"""The outer surface of solid meshes (for pictures) and where sensors and loads act."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.elements import element_family
from fe_core.mesh import Block, mesh_blocks
from fe_core.surface import boundary_faces, cell_type_of, dof_arrows, face_normals
from fe_core.tet_mesh import box_tets

SIZE = (0.3, 0.04, 0.03)
RTOL = 1e-12  # sums of a few hundred exact products


def _closed_and_outward(nodes, cells, faces, owner):
    """Every edge of the surface is shared by exactly two faces, traversed once in each direction
    (a closed, consistently oriented surface), and Gauss's theorem gives the volume."""
    k = faces.shape[1]
    edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == edges.shape[0], "an edge is traversed twice in the same direction"
    assert all((b, a) in directed for a, b in directed), "an edge belongs to one face only"
    # div x = 3: the surface integral of x . n is three times the volume.
    flux = np.einsum("ij,ij->", nodes[faces].mean(axis=1), face_normals(nodes, faces))
    volume = element_family(cell_type_of(cells)).element_volumes(nodes[cells]).sum()
    assert flux == pytest.approx(3.0 * volume, rel=RTOL)
    assert owner.shape == (faces.shape[0],) and k in (3, 4)


@pytest.mark.parametrize("order", [1, 2])
def test_the_boundary_of_a_tet_box_is_its_six_sides(order):
    n = (6, 2, 1)
    nodes, cells = box_tets(SIZE, n, order)
    faces, owner = boundary_faces(nodes, cells)
    a, b, c = SIZE
    assert faces.shape == (2 * 2 * (n[0] * n[1] + n[1] * n[2] + n[2] * n[0]), 3)
    area = np.linalg.norm(face_normals(nodes, faces), axis=1).sum()
    assert area == pytest.approx(2 * (a * b + b * c + c * a), rel=RTOL)
    assert set(np.unique(faces)) <= set(np.unique(cells[:, :4]))  # corners only, tet10 too
    _closed_and_outward(nodes, cells, faces, owner)


def test_the_boundary_of_a_hex_mesh_with_a_step():
    """Two blocks of different height share a face: the shared part is inside, the step outside."""
    mesh = mesh_blocks([Block(np.linspace(0, 0.2, 5), np.linspace(0, 0.1, 3), np.linspace(0, 0.04, 3), "low"),
                        Block(np.linspace(0.2, 0.3, 3), np.linspace(0, 0.1, 3), np.linspace(0, 0.08, 5), "high")])
    faces, owner = boundary_faces(mesh.nodes, mesh.cells)
    assert faces.shape[1] == 4
    area = np.linalg.norm(face_normals(mesh.nodes, faces), axis=1).sum()
    # two boxes' surfaces minus twice the shared 0.1 x 0.04 patch
    want = 2 * (0.2 * 0.1 + 0.1 * 0.04 + 0.04 * 0.2) + 2 * (0.1 * 0.1 + 0.1 * 0.08 + 0.08 * 0.1) - 2 * 0.1 * 0.04
    assert area == pytest.approx(want, rel=RTOL)
    _closed_and_outward(mesh.nodes, mesh.cells, faces, owner)


def test_the_benchmark_surface_is_closed(benchmark_model):
    mesh = benchmark_model.mesh
    faces, owner = boundary_faces(mesh.nodes, mesh.cells)
    _closed_and_outward(mesh.nodes, mesh.cells, faces, owner)


def test_cell_types_by_width():
    assert [cell_type_of(np.zeros((1, k), int)) for k in (4, 8, 10)] == ["tetra", "hexahedron", "tetra10"]
    with pytest.raises(ValueError, match="20 nodes per cell"):
        cell_type_of(np.zeros((1, 20), int))


def test_sensor_and_excitation_arrows_are_at_their_points(box_model_file):
    from fe_core.io import read_model

    model = read_model(box_model_file)
    L = model.outputs.tocsc()
    want = {"tip_z": ([0.3, 0.0, 0.03], [0, 0, 1]), "tip_y": ([0.3, 0.04, 0.03], [0, 1, 0]),
            "mid_z": ([0.15, 0.0, 0.03], [0, 0, 1])}
    for j, name in enumerate(model.sensor_names):
        arrows = dof_arrows(model, L[:, j])
        np.testing.assert_allclose(arrows.positions, [want[name][0]], atol=1e-15)
        np.testing.assert_allclose(arrows.directions, [want[name][1]], atol=1e-15)
    exc = dof_arrows(model, model.load)  # z with weight 1 and y with weight 0.5 at one node
    np.testing.assert_allclose(exc.positions, [[0.3, 0.02, 0.03]], atol=1e-15)
    np.testing.assert_allclose(exc.directions, [np.array([0, 0.5, 1.0]) / np.sqrt(1.25)], rtol=1e-15)
    np.testing.assert_allclose(exc.weights, [np.sqrt(1.25)], rtol=1e-15)
