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

_GRADIENTS = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def shape_functions(xi: np.ndarray) -> np.ndarray:
    """``N_a(xi)``, shape (p, 4), for reference points ``xi`` of shape (p, 3)."""
    return _tet.barycentric(np.asarray(xi, dtype=float))


def shape_gradients(xi: np.ndarray) -> np.ndarray:
    """``dN_a / dxi_i``, shape (p, 4, 3) (constant)."""
    return np.broadcast_to(_GRADIENTS, (np.asarray(xi).shape[0], 4, 3))


def element_stiffness(coords: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Element stiffness matrices.

    Parameters
    ----------
    coords : ndarray, shape (n_elements, 4, 3), m
    D : ndarray, shape (6, 6), Pa
        For strains ``[exx, eyy, ezz, gxy, gyz, gzx]``.

    Returns
    -------
    ndarray, shape (n_elements, 12, 12), N/m

    Raises
    ------
    ValueError
        Naming the first inverted or degenerate element.
    """
    return _tet.isoparametric_stiffness(coords, D, shape_gradients, 1, _tet.VERTICES[:0])


def element_mass(coords: np.ndarray, rho: float) -> np.ndarray:
    """Consistent element mass, shape (n_elements, 12, 12), kg (``rho`` in kg/m^3)."""
    return _tet.isoparametric_mass(coords, rho, shape_functions, shape_gradients, 2)


def element_volumes(coords: np.ndarray) -> np.ndarray:
    """Signed volumes, shape (n_elements,), m^3 (negative for an inverted cell)."""
    return _tet.volumes(coords, shape_gradients, 1)


def check_cells(coords: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first inverted or degenerate cell (as :func:`element_stiffness`)."""
    _tet.check_jacobians(_tet.jacobians_at(coords, shape_gradients, 1, _tet.VERTICES[:0]), np.asarray(coords, dtype=float))
