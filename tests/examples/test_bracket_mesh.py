"""The L-bracket example mesh: meshio reads its groups, its cells are sound tet10, and the
gmsh script that made it runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fe_core.elements import tet10

meshio = pytest.importorskip("meshio")

FOLDER = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket"
SEGMENTS = {"foot_inner", "foot_outer", "web_lower", "web_upper", "rib_left", "rib_right"}
NODE_SETS = {"foot_bottom", "bolt_holes", "web_top"}

# The CAD volume, m^3: foot with two bolt holes, web above the foot, two triangular ribs.
FOOT = 0.12 * 0.08 * 0.01 - 2 * np.pi * 0.0045**2 * 0.01
VOLUME = FOOT + 0.01 * 0.08 * 0.11 + 2 * 0.5 * 0.05**2 * 0.008


def check_bracket(path: Path) -> "meshio.Mesh":
    mesh = meshio.read(path)
    assert set(mesh.field_data) == SEGMENTS | NODE_SETS
    assert {name for name, (tag, dim) in mesh.field_data.items() if dim == 3} == SEGMENTS
    assert {c.type for c in mesh.cells} == {"tetra10", "triangle6"}
    cells = mesh.cells_dict["tetra10"]
    coords = mesh.points[cells]
    tet10.check_cells(coords)
    # Mid-edge nodes sit near their edges' midpoints (meshio's order is VTK's; a wrong order
    # would put them half an edge away or more); only the ones on the curved holes are off.
    offset = np.linalg.norm(coords[:, 4:] - coords[:, tet10.EDGES].mean(axis=2), axis=2)
    edge = np.linalg.norm(coords[:, tet10.EDGES[:, 0]] - coords[:, tet10.EDGES[:, 1]], axis=2)
    assert np.max(offset / edge) < 0.2  # a 60-degree arc bulges 0.13 of its chord
    # Quadratic cells represent the holes' cylinders closely.
    assert tet10.element_volumes(coords).sum() == pytest.approx(VOLUME, rel=1e-4)
    # Every tetra10 cell lies in exactly one segment.
    sets = mesh.cell_sets_dict
    members = np.concatenate([sets[name]["tetra10"] for name in SEGMENTS])
    assert np.array_equal(np.sort(members), np.arange(len(cells)))
    # The support faces: the foot's underside is flat at z = 0, the holes are cylinders.
    bottom = mesh.points[np.unique(mesh.cells_dict["triangle6"][sets["foot_bottom"]["triangle6"]])]
    assert np.abs(bottom[:, 2]).max() < 1e-12
    holes = mesh.points[np.unique(mesh.cells_dict["triangle6"][sets["bolt_holes"]["triangle6"]])]
    radius = np.min([np.hypot(holes[:, 0] - 0.095, holes[:, 1] - y) for y in (0.02, 0.06)], axis=0)
    np.testing.assert_allclose(radius, 0.0045, atol=1e-9)
    return mesh


@pytest.mark.parametrize(
    "name, dofs", [("bracket.msh", (20_000, 60_000)), ("bracket_coarse.msh", (3_000, 12_000))]
)
def test_committed_meshes_read_with_their_groups(name, dofs):
    mesh = check_bracket(FOLDER / name)
    assert dofs[0] <= 3 * len(mesh.points) <= dofs[1]


def test_make_mesh_script_builds_the_same_groups(tmp_path):
    pytest.importorskip("gmsh")
    out = tmp_path / "b.msh"
    subprocess.run([sys.executable, str(FOLDER / "make_mesh.py"), "--size", "0.03", "--out", str(out)], check=True)
    check_bracket(out)
