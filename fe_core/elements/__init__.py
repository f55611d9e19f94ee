"""Element families, one module each, behind one registry keyed by meshio's cell type.

Every element module exposes the same small interface, vectorised over elements:

``NODES`` : int
    Nodes per cell, in meshio's (VTK's) node order.
``element_stiffness(coords, D, **options) -> (n, 3 * NODES, 3 * NODES)``
    ``coords`` of shape ``(n, NODES, 3)`` in m, ``D`` the 6 x 6 elasticity matrix
    for strains ``[exx, eyy, ezz, gxy, gyz, gzx]`` in Pa; N/m. Raises ``ValueError``
    naming the first element with a non-positive Jacobian.
``element_mass(coords, rho) -> (n, 3 * NODES, 3 * NODES)``
    Consistent mass, kg.
``element_volumes(coords) -> (n,)``
    Signed cell volumes, m^3 (``rho * V`` is the cell's mass).
``check_cells(coords) -> None``
    Raises the same ``ValueError`` as ``element_stiffness`` for inverted or
    degenerate cells (det J at most 1e-10 of the cell's size cubed, see
    ``_common.check_jacobians``), without computing matrices: a model reader
    calls it to refuse a mesh before any work.

Element DOFs are node-major, ``[u_x0, u_y0, u_z0, u_x1, ...]``. A new family is one
module plus one line in :data:`ELEMENTS`.
"""

from __future__ import annotations

from types import ModuleType

from . import hex8, tet4, tet10

__all__ = ["ELEMENTS", "element_family"]

#: meshio cell type -> element module.
ELEMENTS: dict[str, ModuleType] = {
    "hexahedron": hex8,
    "tetra": tet4,
    "tetra10": tet10,
}


def element_family(cell_type: str) -> ModuleType:
    """The element module for a meshio cell type; ``ValueError`` naming the supported ones."""
    try:
        return ELEMENTS[cell_type]
    except KeyError:
        raise ValueError(
            f"unsupported element type {cell_type!r}; supported: {', '.join(sorted(ELEMENTS))}"
        ) from None
