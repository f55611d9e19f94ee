"""Eight-node hexahedron: shape functions, element stiffness and consistent mass.

Two stiffness formulations share one code path:

``"incompatible"`` (default, the benchmark element)
    Wilson's incompatible-modes hexahedron with Taylor's correction (QM6 type).
    The trilinear field is enriched by the bubble modes ``P_k = 1 - xi_k^2``
    acting on each displacement component (9 internal DOFs). Their gradients
    are evaluated with the centre Jacobian, ``dP/dx = (det J0 / det J)
    J0^-T dP/dxi``, which makes the element pass the patch test on distorted
    meshes. The internal DOFs are condensed per element:
    ``K_e = K_uu - K_uq K_qq^-1 K_uq^T``.
``"plain"``
    Full-integration trilinear hexahedron. It locks in bending and is kept
    only as an option and as a reference for cross-checks.

The consistent mass matrix ``rho * sum N^T N det J`` uses the same 2x2x2 Gauss
rule; it is exact for parallelepipeds.

Node order (reference coordinates)::

    0 (-1,-1,-1)  1 (+1,-1,-1)  2 (+1,+1,-1)  3 (-1,+1,-1)
    4 (-1,-1,+1)  5 (+1,-1,+1)  6 (+1,+1,+1)  7 (-1,+1,+1)

Element DOFs are node-major, ``[u_x0, u_y0, u_z0, u_x1, ...]`` (24 per
element), and strains are ordered ``[exx, eyy, ezz, gxy, gyz, gzx]``.
All functions are vectorised over elements: coordinates come as
``(n_elements, 8, 3)`` arrays.
"""

from __future__ import annotations

import numpy as np

from ._common import check_jacobians

__all__ = [
    "NODES",
    "NODE_SIGNS",
    "FORMULATIONS",
    "gauss_points",
    "shape_functions",
    "shape_gradients",
    "strain_matrix",
    "element_stiffness",
    "element_mass",
    "element_volumes",
    "check_cells",
]

#: Reference coordinates of the 8 nodes, shape (8, 3).
NODE_SIGNS = np.array(
    [
        [-1, -1, -1],
        [+1, -1, -1],
        [+1, +1, -1],
        [-1, +1, -1],
        [-1, -1, +1],
        [+1, -1, +1],
        [+1, +1, +1],
        [-1, +1, +1],
    ],
    dtype=float,
)

FORMULATIONS = ("incompatible", "plain")

#: Nodes per cell (meshio "hexahedron", VTK order).
NODES = 8


def gauss_points() -> tuple[np.ndarray, np.ndarray]:
    """The 2x2x2 Gauss rule on the reference cube.

    Returns
    -------
    points : ndarray, shape (8, 3)
    weights : ndarray, shape (8,)
        All ones.
    """
    g = 1.0 / np.sqrt(3.0)
    return NODE_SIGNS * g, np.ones(8)


def shape_functions(xi: np.ndarray) -> np.ndarray:
    """Trilinear shape functions ``N_a = (1 + xi xi_a)(1 + eta eta_a)(1 + zeta zeta_a) / 8``.

    Parameters
    ----------
    xi : ndarray, shape (n_points, 3)

    Returns
    -------
    ndarray, shape (n_points, 8)
    """
    return np.prod(1.0 + xi[:, None, :] * NODE_SIGNS[None, :, :], axis=2) / 8.0


def shape_gradients(xi: np.ndarray) -> np.ndarray:
    """Derivatives of the shape functions with respect to the reference coordinates.

    Parameters
    ----------
    xi : ndarray, shape (n_points, 3)

    Returns
    -------
    ndarray, shape (n_points, 8, 3)
        ``[p, a, i] = dN_a / dxi_i`` at point p.
    """
    factors = 1.0 + xi[:, None, :] * NODE_SIGNS[None, :, :]  # (p, 8, 3)
    grads = np.empty_like(factors)
    for i in range(3):
        others = [j for j in range(3) if j != i]
        grads[:, :, i] = NODE_SIGNS[None, :, i] * factors[:, :, others[0]] * factors[:, :, others[1]]
    return grads / 8.0


def _bubble_gradients(xi: np.ndarray) -> np.ndarray:
    """Reference gradients of the bubble modes ``P_k = 1 - xi_k^2``, shape (n_points, 3, 3).

    ``[p, k, i] = dP_k / dxi_i``; only the diagonal is non-zero.
    """
    grads = np.zeros((xi.shape[0], 3, 3))
    for k in range(3):
        grads[:, k, k] = -2.0 * xi[:, k]
    return grads


def strain_matrix(grad_x: np.ndarray) -> np.ndarray:
    """Strain-displacement matrix from physical gradients of a set of scalar modes.

    Parameters
    ----------
    grad_x : ndarray, shape (..., n_modes, 3)
        ``dphi_a / dx_i`` for each mode a.

    Returns
    -------
    ndarray, shape (..., 6, 3 * n_modes)
        Rows ``[exx, eyy, ezz, gxy, gyz, gzx]``, columns mode-major
        ``[u_x, u_y, u_z]`` per mode.
    """
    lead = grad_x.shape[:-2]
    n = grad_x.shape[-2]
    dx, dy, dz = grad_x[..., 0], grad_x[..., 1], grad_x[..., 2]
    B = np.zeros(lead + (6, n, 3))
    B[..., 0, :, 0] = dx
    B[..., 1, :, 1] = dy
    B[..., 2, :, 2] = dz
    B[..., 3, :, 0] = dy
    B[..., 3, :, 1] = dx
    B[..., 4, :, 1] = dz
    B[..., 4, :, 2] = dy
    B[..., 5, :, 0] = dz
    B[..., 5, :, 2] = dx
    return B.reshape(lead + (6, 3 * n))


def _jacobians(coords: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``J[e, p, i, j] = dx_j / dxi_i`` for elements e at points p."""
    return np.einsum("pai,eaj->epij", shape_gradients(xi), coords)


def element_stiffness(
    coords: np.ndarray, D: np.ndarray, formulation: str = "incompatible"
) -> np.ndarray:
    """Element stiffness matrices.

    Parameters
    ----------
    coords : ndarray, shape (n_elements, 8, 3), m
        Node coordinates in the order of :data:`NODE_SIGNS`.
    D : ndarray, shape (6, 6), Pa
        Elasticity matrix for the strain order ``[exx, eyy, ezz, gxy, gyz, gzx]``.
    formulation : {"incompatible", "plain"}

    Returns
    -------
    ndarray, shape (n_elements, 24, 24), N/m
        Symmetric; internal modes already condensed.

    Raises
    ------
    ValueError
        For an unknown formulation or an element with non-positive Jacobian.
    """
    if formulation not in FORMULATIONS:
        raise ValueError(f"unknown hex8 formulation {formulation!r}; choose one of {FORMULATIONS}")
    coords = np.asarray(coords, dtype=float)
    xi, w = gauss_points()
    J = _jacobians(coords, xi)  # (e, p, 3, 3)
    detJ = np.linalg.det(J)
    check_jacobians(detJ, coords)
    Jinv = np.linalg.inv(J)
    # dN/dx = J^-1 dN/dxi, written per node: grad_x[e,p,a,:] = Jinv[e,p] @ dN[p,a,:]
    grad_x = np.einsum("epij,paj->epai", Jinv, shape_gradients(xi))
    B = strain_matrix(grad_x)  # (e, p, 6, 24)
    wdet = detJ * w[None, :]
    DB = np.einsum("ij,epjk->epik", D, B)
    Kuu = np.einsum("epji,epjk,ep->eik", B, DB, wdet)
    if formulation == "plain":
        return 0.5 * (Kuu + Kuu.transpose(0, 2, 1))

    # Taylor's correction: centre Jacobian and the ratio detJ0 / detJ.
    J0 = _jacobians(coords, np.zeros((1, 3)))[:, 0]  # (e, 3, 3)
    detJ0 = np.linalg.det(J0)
    J0inv = np.linalg.inv(J0)
    grad_q = np.einsum("eij,pkj->epki", J0inv, _bubble_gradients(xi))
    grad_q *= (detJ0[:, None] / detJ)[:, :, None, None]
    G = strain_matrix(grad_q)  # (e, p, 6, 9)
    DG = np.einsum("ij,epjk->epik", D, G)
    Kuq = np.einsum("epji,epjk,ep->eik", B, DG, wdet)
    Kqq = np.einsum("epji,epjk,ep->eik", G, DG, wdet)
    Ke = Kuu - Kuq @ np.linalg.solve(Kqq, Kuq.transpose(0, 2, 1))
    return 0.5 * (Ke + Ke.transpose(0, 2, 1))


def element_mass(coords: np.ndarray, rho: float) -> np.ndarray:
    """Consistent element mass matrices ``rho * sum N^T N det J`` (2x2x2 Gauss).

    Parameters
    ----------
    coords : ndarray, shape (n_elements, 8, 3), m
    rho : float, kg/m^3

    Returns
    -------
    ndarray, shape (n_elements, 24, 24), kg
        The same scalar 8x8 matrix for u_x, u_y and u_z.
    """
    coords = np.asarray(coords, dtype=float)
    xi, w = gauss_points()
    detJ = np.linalg.det(_jacobians(coords, xi))
    N = shape_functions(xi)  # (p, 8)
    Ms = rho * np.einsum("pa,pb,ep->eab", N, N, detJ * w[None, :])
    Me = np.zeros((coords.shape[0], 8, 3, 8, 3))
    for c in range(3):
        Me[:, :, c, :, c] = Ms
    return Me.reshape(coords.shape[0], 24, 24)


def check_cells(coords: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first cell with non-positive det J at a Gauss point."""
    coords = np.asarray(coords, dtype=float)
    check_jacobians(np.linalg.det(_jacobians(coords, gauss_points()[0])), coords)


def element_volumes(coords: np.ndarray) -> np.ndarray:
    """Signed volumes ``sum det J`` (2x2x2 Gauss), shape (n_elements,), m^3."""
    xi, w = gauss_points()
    return np.linalg.det(_jacobians(np.asarray(coords, dtype=float), xi)) @ w
