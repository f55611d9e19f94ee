"""Four-node linear tetrahedron (meshio ``"tetra"``): constant strain.

Shape functions are the barycentric coordinates ``N_a = L_a`` of the reference
tetrahedron (0,0,0), (1,0,0), (0,1,0), (0,0,1). The stiffness is exact with one
point; the consistent mass (degree 2) with the symmetric 4-point rule.

Element DOFs are node-major, ``[u_x0, u_y0, u_z0, u_x1, ...]`` (12 per element);
functions are vectorised over elements: coordinates come as ``(n_elements, 4, 3)``.
The element is stiff in bending (it locks); use tet10 for CAD geometry where
accuracy matters.
"""

from __future__ import annotations

import numpy as np

from . import _tet

__all__ = [
    "NODES",
    "shape_functions",
    "shape_gradients",
    "element_stiffness",
    "element_mass",
    "element_volumes",
    "check_cells",
]

#: Nodes per cell (meshio "tetra", VTK order).
NODES = 4

def shape_functions(xi: np.ndarray) -> np.ndarray:
    """``N_a(xi)``, shape (p, 4), for reference points ``xi`` of shape (p, 3)."""
    return _tet.barycentric(np.asarray(xi, dtype=float))


def shape_gradients(xi: np.ndarray) -> np.ndarray:
    """``dN_a / dxi_i``, shape (p, 4, 3) (constant)."""
    return np.broadcast_to(_tet.BARYCENTRIC_GRADIENTS, (np.asarray(xi).shape[0], 4, 3))


element_stiffness, element_mass, element_volumes, check_cells = _tet.family_functions(
    NODES, shape_functions, shape_gradients, stiffness_degree=1, mass_degree=2, check_points=_tet.VERTICES[:0]
)
