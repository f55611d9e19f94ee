"""What the tetrahedral families share: quadrature on the unit tetrahedron and the
isoparametric stiffness, mass and Jacobian check for any set of shape functions.

The reference tetrahedron has vertices (0,0,0), (1,0,0), (0,1,0), (0,0,1); its
barycentric coordinates are ``L = (1 - x - y - z, x, y, z)``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import roots_jacobi

from ._common import DEGENERATE_RTOL, check_jacobians
from .hex8 import strain_matrix

__all__ = [
    "VERTICES",
    "BARYCENTRIC_GRADIENTS",
    "DEGENERATE_RTOL",
    "quadrature",
    "barycentric",
    "isoparametric_stiffness",
    "isoparametric_mass",
    "check_jacobians",
    "jacobians_at",
    "volumes",
    "family_functions",
]

#: Reference vertex coordinates, shape (4, 3).
VERTICES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

#: Reference gradients of the barycentric coordinates ``L``, shape (4, 3).
BARYCENTRIC_GRADIENTS = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])



@lru_cache(maxsize=None)
def quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A rule on the reference tetrahedron exact for polynomials of total degree ``degree``.

    Degree 1: the centroid. Degree 2: the classical symmetric 4-point rule. Higher:
    Stroud's conical product (Gauss-Jacobi in the collapsed coordinates, all
    weights positive), ``ceil((degree + 1) / 2)**3`` points.

    Returns
    -------
    points : ndarray, shape (p, 3)
    weights : ndarray, shape (p,)
        Sum to 1/6, the reference volume.
    """
    if degree <= 1:
        return np.full((1, 3), 0.25), np.array([1.0 / 6.0])
    if degree == 2:
        a, b = (5.0 - np.sqrt(5.0)) / 20.0, (5.0 + 3.0 * np.sqrt(5.0)) / 20.0
        points = np.full((4, 3), a)
        points[np.arange(1, 4), np.arange(3)] = b  # (a,a,a), (b,a,a), (a,b,a), (a,a,b)
        return points, np.full(4, 1.0 / 24.0)
    n = (degree + 2) // 2
    # Collapsed coordinates t in [0, 1]: x = t1, y = t2 (1 - t1), z = t3 (1 - t1)(1 - t2),
    # with Jacobian (1 - t1)^2 (1 - t2): Gauss-Jacobi weights (1 - t)^2 and (1 - t)^1.
    rules = []
    for alpha in (2, 1, 0):
        x, w = roots_jacobi(n, alpha, 0)
        rules.append(((x + 1.0) / 2.0, w / 2.0 ** (alpha + 1)))
    (t1, w1), (t2, w2), (t3, w3) = rules
    T1, T2, T3 = np.meshgrid(t1, t2, t3, indexing="ij")
    W = (w1[:, None, None] * w2[None, :, None] * w3[None, None, :]).ravel()
    x = T1.ravel()
    y = (T2 * (1.0 - T1)).ravel()
    z = (T3 * (1.0 - T1) * (1.0 - T2)).ravel()
    return np.column_stack([x, y, z]), W


def barycentric(xi: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of reference points, shape (p, 4)."""
    return np.column_stack([1.0 - xi.sum(axis=1), xi])


def _jacobians(dN: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """``J[e, p, i, j] = dx_j / dxi_i`` from reference gradients ``dN`` (p, a, 3)."""
    return np.einsum("pai,eaj->epij", dN, coords)


def jacobians_at(coords, shape_gradients, degree, check_points) -> np.ndarray:
    """det J at the points of the degree-``degree`` rule and at ``check_points``, shape (n, p + q)."""
    coords = np.asarray(coords, dtype=float)
    xi = np.concatenate([quadrature(degree)[0], check_points])
    return np.linalg.det(_jacobians(shape_gradients(xi), coords))


def isoparametric_stiffness(coords, D, shape_gradients, degree, check_points) -> np.ndarray:
    """``sum_p w_p B_p^T D B_p det J_p`` for shape functions with the given reference gradients.

    Parameters
    ----------
    coords : ndarray, shape (n_elements, n_nodes, 3), m
    D : ndarray, shape (6, 6), Pa
    shape_gradients : callable, (p, 3) -> (p, n_nodes, 3)
    degree : int
        Degree of the quadrature rule.
    check_points : ndarray, shape (q, 3)
        Extra reference points where det J must be positive (the corners).

    Returns
    -------
    ndarray, shape (n_elements, 3 n_nodes, 3 n_nodes), N/m
    """
    coords = np.asarray(coords, dtype=float)
    xi, w = quadrature(degree)
    dN = shape_gradients(xi)
    J = _jacobians(dN, coords)
    detJ = np.linalg.det(J)
    at_checks = np.linalg.det(_jacobians(shape_gradients(check_points), coords))
    check_jacobians(np.concatenate([detJ, at_checks], axis=1), coords)
    grad_x = np.einsum("epij,paj->epai", np.linalg.inv(J), dN)
    B = strain_matrix(grad_x)  # (e, p, 6, d)
    n_el, p, _, d = B.shape
    DB = (D @ B) * (detJ * w)[:, :, None, None]
    # sum over points and strains as one batched matrix product: (e, d, 6p) @ (e, 6p, d)
    K = B.reshape(n_el, p * 6, d).transpose(0, 2, 1) @ DB.reshape(n_el, p * 6, d)
    return 0.5 * (K + K.transpose(0, 2, 1))


def isoparametric_mass(coords, rho, shape_functions, shape_gradients, degree) -> np.ndarray:
    """Consistent mass ``rho sum_p w_p N_p^T N_p det J_p``, the same block for x, y and z.

    Returns
    -------
    ndarray, shape (n_elements, 3 n_nodes, 3 n_nodes), kg
    """
    coords = np.asarray(coords, dtype=float)
    xi, w = quadrature(degree)
    detJ = np.linalg.det(_jacobians(shape_gradients(xi), coords))
    N = shape_functions(xi)  # (p, a)
    Ms = rho * np.einsum("pa,pb,ep->eab", N, N, detJ * w[None, :])
    n_el, a = Ms.shape[:2]
    Me = np.zeros((n_el, a, 3, a, 3))
    for c in range(3):
        Me[:, :, c, :, c] = Ms
    return Me.reshape(n_el, 3 * a, 3 * a)


def volumes(coords, shape_gradients, degree) -> np.ndarray:
    """Signed cell volumes ``sum_p w_p det J_p``, shape (n_elements,), m^3."""
    xi, w = quadrature(degree)
    return np.linalg.det(_jacobians(shape_gradients(xi), np.asarray(coords, dtype=float))) @ w


def family_functions(nodes, shape_functions, shape_gradients, stiffness_degree, mass_degree, check_points):
    """The registry interface of one tetrahedral family.

    Returns
    -------
    element_stiffness, element_mass, element_volumes, check_cells : callables
        With the signatures of :mod:`fe_core.elements` for cells of ``nodes`` nodes.
    """
    d = 3 * nodes

    def element_stiffness(coords: np.ndarray, D: np.ndarray) -> np.ndarray:
        return isoparametric_stiffness(coords, D, shape_gradients, stiffness_degree, check_points)

    def element_mass(coords: np.ndarray, rho: float) -> np.ndarray:
        return isoparametric_mass(coords, rho, shape_functions, shape_gradients, mass_degree)

    def element_volumes(coords: np.ndarray) -> np.ndarray:
        return volumes(coords, shape_gradients, mass_degree)

    def check_cells(coords: np.ndarray) -> None:
        coords = np.asarray(coords, dtype=float)
        check_jacobians(jacobians_at(coords, shape_gradients, stiffness_degree, check_points), coords)

    element_stiffness.__doc__ = f"""Element stiffness matrices.

    Parameters
    ----------
    coords : ndarray, shape (n_elements, {nodes}, 3), m
    D : ndarray, shape (6, 6), Pa
        For strains ``[exx, eyy, ezz, gxy, gyz, gzx]``.

    Returns
    -------
    ndarray, shape (n_elements, {d}, {d}), N/m

    Raises
    ------
    ValueError
        Naming the first inverted or degenerate element.
    """
    element_mass.__doc__ = f"""Consistent element mass, shape (n_elements, {d}, {d}), kg (``rho`` in kg/m^3)."""
    element_volumes.__doc__ = """Signed volumes, shape (n_elements,), m^3 (negative for an inverted cell)."""
    check_cells.__doc__ = """Raise ``ValueError`` naming the first inverted or degenerate cell, as
    ``element_stiffness`` does, without computing matrices."""
    return element_stiffness, element_mass, element_volumes, check_cells
