"""Ten-node quadratic tetrahedron (meshio ``"tetra10"``).

Node order is VTK's (``VTK_QUADRATIC_TETRA``), which meshio uses for every format
(it reorders Gmsh's last two edge nodes on reading): the 4 corners, then the
mid-edge nodes of edges 01, 12, 20, 03, 13, 23. With barycentric ``L`` the shape
functions are ``L_a (2 L_a - 1)`` at the corners and ``4 L_a L_b`` on the edges.

Quadrature: stiffness with the symmetric 4-point rule (degree 2, exact for
straight-sided cells, where B is linear); consistent mass with a degree-4 rule
(27-point conical product, exact for straight-sided cells). Curved cells
(mid-edge nodes moved onto curved CAD surfaces) are integrated approximately, as
in every FE program. The Jacobian is checked at the quadrature points and the
corners.

Element DOFs are node-major (30 per element); functions are vectorised over
elements: coordinates come as ``(n_elements, 10, 3)``.
"""

from __future__ import annotations

import numpy as np

from . import _tet

__all__ = [
    "NODES",
    "EDGES",
    "shape_functions",
    "shape_gradients",
    "element_stiffness",
    "element_mass",
    "element_volumes",
    "check_cells",
]

#: Nodes per cell (meshio "tetra10", VTK order).
NODES = 10

#: Corner pairs of the mid-edge nodes 4..9.
EDGES = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])

STIFFNESS_DEGREE = 2
MASS_DEGREE = 4


def shape_functions(xi: np.ndarray) -> np.ndarray:
    """``N_a(xi)``, shape (p, 10), for reference points ``xi`` of shape (p, 3)."""
    L = _tet.barycentric(np.asarray(xi, dtype=float))
    return np.concatenate([L * (2.0 * L - 1.0), 4.0 * L[:, EDGES[:, 0]] * L[:, EDGES[:, 1]]], axis=1)


def shape_gradients(xi: np.ndarray) -> np.ndarray:
    """``dN_a / dxi_i``, shape (p, 10, 3)."""
    L = _tet.barycentric(np.asarray(xi, dtype=float))  # (p, 4)
    dL = _tet.BARYCENTRIC_GRADIENTS
    corners = (4.0 * L - 1.0)[:, :, None] * dL[None]
    i, j = EDGES[:, 0], EDGES[:, 1]
    edges = 4.0 * (L[:, j, None] * dL[None, i] + L[:, i, None] * dL[None, j])
    return np.concatenate([corners, edges], axis=1)


element_stiffness, element_mass, element_volumes, check_cells = _tet.family_functions(
    NODES, shape_functions, shape_gradients, STIFFNESS_DEGREE, MASS_DEGREE, check_points=_tet.VERTICES
)
