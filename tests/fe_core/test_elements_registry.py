"""The interface every element family of the registry offers, checked family by family."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.elements import ELEMENTS
from fe_core.elements.hex8 import NODE_SIGNS
from fe_core.tet_mesh import box_tets

SIZE = (0.4, 0.3, 0.2)


def box_cells(cell_type: str) -> np.ndarray:
    """Cell coordinates of the box SIZE meshed by the family, shape (n, NODES, 3)."""
    if cell_type == "hexahedron":
        return ((NODE_SIGNS + 1.0) / 2.0 * np.array(SIZE))[None]
    nodes, cells = box_tets(SIZE, (2, 2, 1), order=1 if cell_type == "tetra" else 2)
    return nodes[cells]


@pytest.mark.parametrize("cell_type", sorted(ELEMENTS))
def test_volumes_sum_to_the_box_and_shapes_follow_nodes(cell_type):
    family = ELEMENTS[cell_type]
    coords = box_cells(cell_type)
    assert coords.shape[1] == family.NODES
    assert family.element_volumes(coords).sum() == pytest.approx(np.prod(SIZE), rel=1e-12)
    d = 3 * family.NODES
    assert family.element_mass(coords, 1000.0).shape == (len(coords), d, d)
    family.check_cells(coords)


@pytest.mark.parametrize("cell_type", sorted(ELEMENTS))
def test_mirrored_cell_is_refused_by_index(cell_type):
    family = ELEMENTS[cell_type]
    coords = box_cells(cell_type)
    bad = coords.copy()
    bad[-1] = coords[-1] * np.array([-1.0, 1.0, 1.0])  # mirrored: det J < 0 everywhere
    assert family.element_volumes(bad)[-1] < 0
    with pytest.raises(ValueError, match=rf"element {len(coords) - 1} has a non-positive Jacobian"):
        family.check_cells(bad)



@pytest.mark.parametrize("cell_type", sorted(ELEMENTS))
def test_flattened_cells_are_refused_as_degenerate(cell_type):
    family = ELEMENTS[cell_type]
    coords = box_cells(cell_type) * np.array([1.0, 1.0, 1e-12])  # 0.2 pm thick
    with pytest.raises(ValueError, match=r"element 0 has a non-positive Jacobian \(degenerate cell"):
        family.check_cells(coords)
    with pytest.raises(ValueError, match=r"degenerate"):
        family.element_stiffness(coords, np.eye(6))
