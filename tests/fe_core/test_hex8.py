"""Element invariants of the hex8 formulations, and a cross-check with scikit-fem."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.assembly import assemble, cell_dofs
from fe_core.elements.hex8 import FORMULATIONS, NODE_SIGNS, element_mass, element_stiffness
from fe_core.material import isotropic_elasticity
from fe_core.mesh import Block, mesh_blocks

E, NU, RHO = 2.06e11, 0.3, 7850.0
D = isotropic_elasticity(E, NU)
ZERO_EIG_RTOL = 1e-10  # zero eigenvalues relative to the largest one
EXACT_RTOL = 1e-10


def box(a=1.0, b=1.0, c=1.0, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Node coordinates of one box element, shape (1, 8, 3)."""
    half = (NODE_SIGNS + 1.0) / 2.0
    return (np.asarray(origin) + half * np.array([a, b, c]))[None]


def distorted(rng) -> np.ndarray:
    """A general (non-parallelepiped) hexahedron with positive Jacobian."""
    return box(2.0, 1.0, 0.5) + rng.uniform(-0.15, 0.15, size=(1, 8, 3)) * np.array([2.0, 1.0, 0.5])


def rigid_body_modes(coords: np.ndarray) -> np.ndarray:
    """Three translations and three infinitesimal rotations, shape (24, 6)."""
    x = coords.reshape(-1, 3)
    modes = np.zeros((8, 3, 6))
    for i in range(3):
        modes[:, i, i] = 1.0
    for k, (i, j) in enumerate([(0, 1), (1, 2), (2, 0)]):
        modes[:, i, 3 + k] = -x[:, j]
        modes[:, j, 3 + k] = x[:, i]
    return modes.reshape(24, 6)


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("shape", ["box", "distorted"])
def test_free_element_has_exactly_six_rigid_body_modes(formulation, shape, rng):
    coords = box(2.0, 1.0, 0.5) if shape == "box" else distorted(rng)
    K = element_stiffness(coords, D, formulation)[0]
    np.testing.assert_allclose(K, K.T, rtol=0, atol=1e-12 * np.abs(K).max())
    eig = np.linalg.eigvalsh(K)
    n_zero = np.sum(np.abs(eig) < ZERO_EIG_RTOL * eig.max())
    assert n_zero == 6
    assert eig.min() > -ZERO_EIG_RTOL * eig.max()
    R = rigid_body_modes(coords[0])
    assert np.abs(K @ R).max() < ZERO_EIG_RTOL * np.abs(K).max() * np.abs(R).max()


@pytest.mark.parametrize("shape", ["box", "distorted"])
def test_consistent_mass_is_symmetric_positive_definite_and_sums_to_rho_v(shape, rng):
    coords = box(2.0, 1.0, 0.5) if shape == "box" else distorted(rng)
    Me = element_mass(coords, RHO)[0]
    np.testing.assert_allclose(Me, Me.T)
    assert np.linalg.eigvalsh(Me).min() > 0
    ux = np.tile([1.0, 0.0, 0.0], 8)
    volume = mesh_volume_by_quadrature(coords)
    assert ux @ Me @ ux == pytest.approx(RHO * volume, rel=EXACT_RTOL)


def mesh_volume_by_quadrature(coords):
    from fe_core.elements.hex8 import _jacobians, gauss_points

    xi, w = gauss_points()
    return float((np.linalg.det(_jacobians(coords, xi)) * w).sum())


def pure_bending_field(x: np.ndarray, kappa: float) -> np.ndarray:
    """Exact 3-D pure bending about y (sigma_xx = E kappa z, all else zero), shape (n, 3)."""
    X, Y, Z = x[:, 0], x[:, 1], x[:, 2]
    return np.column_stack(
        [kappa * X * Z, -NU * kappa * Y * Z, -0.5 * kappa * (X**2 + NU * (Z**2 - Y**2))]
    )


def test_incompatible_element_is_exact_in_pure_bending_and_plain_locks():
    a, b, c, kappa = 10.0, 1.0, 1.0, 1e-3  # a slender element: 10 x 1 x 1
    coords = box(a, b, c, origin=(-a / 2, -b / 2, -c / 2))
    u = pure_bending_field(coords[0], kappa).ravel()
    exact = 0.5 * E * kappa**2 * a * b * c**3 / 12.0  # integral of E kappa^2 z^2 / 2
    energy = {f: 0.5 * u @ element_stiffness(coords, D, f)[0] @ u for f in FORMULATIONS}
    assert energy["incompatible"] == pytest.approx(exact, rel=EXACT_RTOL)
    # The plain element's parasitic shear makes it far too stiff for a slender element.
    assert energy["plain"] > 20.0 * exact


def patch_mesh(rng):
    """A 2x2x2 patch whose interior node is moved off-centre: every cell is distorted."""
    lines = np.array([0.0, 1.0, 2.0])
    mesh = mesh_blocks([Block(lines, lines, lines, "patch")])
    centre = mesh.nearest_node([1.0, 1.0, 1.0])
    mesh.nodes[centre] += np.array([0.23, -0.17, 0.11])
    return mesh, centre


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_distorted_patch_reproduces_a_linear_field_exactly(formulation, rng):
    mesh, centre = patch_mesh(rng)
    G = rng.normal(size=(3, 3)) * 1e-3
    u_exact = (mesh.nodes @ G.T + np.array([1e-3, -2e-3, 5e-4])).ravel()
    K = assemble(element_stiffness(mesh.cell_coords, D, formulation), cell_dofs(mesh.cells), mesh.n_nodes * 3)
    inner = 3 * centre + np.arange(3)
    outer = np.setdiff1d(np.arange(mesh.n_nodes * 3), inner)
    K = K.toarray()
    u_inner = np.linalg.solve(K[np.ix_(inner, inner)], -K[np.ix_(inner, outer)] @ u_exact[outer])
    np.testing.assert_allclose(u_inner, u_exact[inner], rtol=1e-9, atol=1e-12)
    # No force at the interior node and no out-of-balance at the boundary for a constant stress.
    residual = K @ u_exact
    assert np.abs(residual[inner]).max() < 1e-9 * np.abs(K @ u_exact).max()


def test_plain_hex8_matches_scikit_fem_on_a_box_mesh():
    skfem = pytest.importorskip("skfem")
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = mesh_blocks([Block(np.array([0.0, 0.3, 0.7]), np.array([0.0, 0.2]), np.array([0.0, 0.1, 0.25]), "b")])
    n = mesh.n_nodes * 3
    K = assemble(element_stiffness(mesh.cell_coords, D, "plain"), cell_dofs(mesh.cells), n).toarray()
    M = assemble(element_mass(mesh.cell_coords, RHO), cell_dofs(mesh.cells), n).toarray()

    sk_mesh = skfem.MeshHex.init_tensor(np.array([0.0, 0.3, 0.7]), np.array([0.0, 0.2]), np.array([0.0, 0.1, 0.25]))
    basis = skfem.Basis(sk_mesh, skfem.ElementVector(skfem.ElementHex1()), intorder=3)
    K_sk = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis).toarray()

    @skfem.BilinearForm
    def mass(u, v, w):
        return RHO * skfem.helpers.dot(u, v)

    M_sk = skfem.asm(mass, basis).toarray()
    # Map scikit-fem's DOFs onto ours through node coordinates and components.
    ours = np.array([mesh.nearest_node(p) for p in sk_mesh.p.T])
    perm = np.empty(n, dtype=int)
    for comp in range(3):
        perm[basis.nodal_dofs[comp]] = 3 * ours + comp
    P = np.zeros((n, n))
    P[np.arange(n), perm] = 1.0  # row i of ours-space -> sk dof i
    np.testing.assert_allclose(P @ K @ P.T, K_sk, rtol=0, atol=1e-9 * np.abs(K_sk).max())
    np.testing.assert_allclose(P @ M @ P.T, M_sk, rtol=0, atol=1e-12 * np.abs(M_sk).max())
