"""Element invariants of tet4 and tet10, a cross-check with scikit-fem, and the
convergence of a cantilever's first bending frequency toward beam theory."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from fe_core.assembly import assemble, free_dof_map
from fe_core.elements import ELEMENTS, element_family, tet10
from fe_core.material import isotropic_elasticity
from fe_core.tet_mesh import box_tets

E, NU, RHO = 2.06e11, 0.3, 7850.0
D = isotropic_elasticity(E, NU)
ZERO_EIG_RTOL = 1e-10  # zero eigenvalues relative to the largest one
EXACT_RTOL = 1e-10

FAMILIES = {"tet4": ("tetra", 1), "tet10": ("tetra10", 2)}


def dofs_of(cells: np.ndarray) -> np.ndarray:
    return (3 * cells[:, :, None] + np.arange(3)).reshape(cells.shape[0], -1)


def one_tet(order: int, rng) -> np.ndarray:
    """A general straight-sided tetrahedron, shape (1, 4 or 10, 3)."""
    corners = np.array([[0.0, 0.0, 0.0], [1.3, 0.1, -0.2], [0.2, 0.9, 0.1], [0.1, 0.3, 0.8]])
    corners = corners + rng.uniform(-0.05, 0.05, size=corners.shape)
    if order == 2:
        corners = np.vstack([corners, corners[tet10.EDGES].mean(axis=1)])
    return corners[None]


def distorted_box(order: int, rng, cells=(2, 2, 2), size=(2.0, 1.0, 1.5)):
    """A structured box mesh whose interior corner nodes are moved at random (cells stay
    straight-sided: mid-edge nodes are put back at the midpoints)."""
    nodes, cells = box_tets(size, cells, order)
    corner_ids = np.unique(cells[:, :4])
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    inner = corner_ids[np.all((nodes[corner_ids] > lo + 1e-9) & (nodes[corner_ids] < hi - 1e-9), axis=1)]
    nodes = nodes.copy()
    nodes[inner] += rng.uniform(-0.12, 0.12, size=(inner.size, 3))
    if order == 2:
        nodes[cells[:, 4:]] = nodes[cells[:, tet10.EDGES]].mean(axis=2)
    return nodes, cells


def rigid_body_modes(x: np.ndarray) -> np.ndarray:
    """Three translations and three infinitesimal rotations at nodes x, shape (3 n, 6)."""
    modes = np.zeros((x.shape[0], 3, 6))
    for i in range(3):
        modes[:, i, i] = 1.0
    for k, (i, j) in enumerate([(0, 1), (1, 2), (2, 0)]):
        modes[:, i, 3 + k] = -x[:, j]
        modes[:, j, 3 + k] = x[:, i]
    return modes.reshape(-1, 6)


def test_registry_holds_the_tetrahedra_and_refuses_unknown_types():
    assert ELEMENTS["tetra"].NODES == 4 and ELEMENTS["tetra10"].NODES == 10
    with pytest.raises(ValueError, match="'wedge'.*hexahedron, tetra, tetra10"):
        element_family("wedge")


@pytest.mark.parametrize("family", FAMILIES)
def test_free_element_has_exactly_six_rigid_body_modes(family, rng):
    cell_type, order = FAMILIES[family]
    coords = one_tet(order, rng)
    K = ELEMENTS[cell_type].element_stiffness(coords, D)[0]
    np.testing.assert_allclose(K, K.T, rtol=0, atol=1e-12 * np.abs(K).max())
    eig = np.linalg.eigvalsh(K)
    assert np.sum(np.abs(eig) < ZERO_EIG_RTOL * eig.max()) == 6
    assert eig.min() > -ZERO_EIG_RTOL * eig.max()
    R = rigid_body_modes(coords[0])
    assert np.abs(K @ R).max() < ZERO_EIG_RTOL * np.abs(K).max() * np.abs(R).max()


@pytest.mark.parametrize("family", FAMILIES)
def test_free_patch_has_exactly_six_rigid_body_modes(family, rng):
    cell_type, order = FAMILIES[family]
    nodes, cells = distorted_box(order, rng, cells=(2, 1, 1))
    module = ELEMENTS[cell_type]
    K = assemble(module.element_stiffness(nodes[cells], D), dofs_of(cells), 3 * len(nodes)).toarray()
    eig = np.linalg.eigvalsh(K)
    assert np.sum(np.abs(eig) < ZERO_EIG_RTOL * eig.max()) == 6


@pytest.mark.parametrize("family", FAMILIES)
def test_consistent_mass_is_positive_definite_and_sums_to_rho_v(family, rng):
    cell_type, order = FAMILIES[family]
    module = ELEMENTS[cell_type]
    coords = one_tet(order, rng)
    corners = coords[0, :4]
    volume = np.linalg.det(corners[1:] - corners[0]) / 6.0
    Me = module.element_mass(coords, RHO)[0]
    np.testing.assert_allclose(Me, Me.T)
    assert np.linalg.eigvalsh(Me).min() > 0
    for c in range(3):
        u = np.zeros((module.NODES, 3))
        u[:, c] = 1.0
        assert u.ravel() @ Me @ u.ravel() == pytest.approx(RHO * volume, rel=EXACT_RTOL)
    assert module.element_volumes(coords)[0] == pytest.approx(volume, rel=EXACT_RTOL)
    # A whole box: the cells' masses add up to rho * lx * ly * lz.
    nodes, cells = distorted_box(order, rng)
    M = assemble(module.element_mass(nodes[cells], RHO), dofs_of(cells), 3 * len(nodes))
    ux = np.tile([1.0, 0.0, 0.0], len(nodes))
    assert ux @ (M @ ux) == pytest.approx(RHO * 2.0 * 1.0 * 1.5, rel=EXACT_RTOL)


@pytest.mark.parametrize("family", FAMILIES)
def test_distorted_patch_reproduces_a_linear_field_exactly(family, rng):
    cell_type, order = FAMILIES[family]
    nodes, cells = distorted_box(order, rng)
    module = ELEMENTS[cell_type]
    G = rng.normal(size=(3, 3)) * 1e-3
    u_exact = (nodes @ G.T + np.array([1e-3, -2e-3, 5e-4])).ravel()
    K = assemble(module.element_stiffness(nodes[cells], D), dofs_of(cells), 3 * len(nodes)).toarray()
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    interior = np.flatnonzero(np.all((nodes > lo + 1e-9) & (nodes < hi - 1e-9), axis=1))
    assert interior.size > 0
    inner = (3 * interior[:, None] + np.arange(3)).ravel()
    outer = np.setdiff1d(np.arange(K.shape[0]), inner)
    u_inner = np.linalg.solve(K[np.ix_(inner, inner)], -K[np.ix_(inner, outer)] @ u_exact[outer])
    np.testing.assert_allclose(u_inner, u_exact[inner], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("family", FAMILIES)
def test_inverted_and_degenerate_cells_are_named(family, rng):
    cell_type, order = FAMILIES[family]
    module = ELEMENTS[cell_type]
    good = one_tet(order, rng)[0]
    inverted = good.copy()
    inverted[[1, 2]] = good[[2, 1]]  # swap two corners
    if order == 2:
        inverted[4:] = inverted[tet10.EDGES].mean(axis=1)
    flat = good.copy()
    flat[3] = flat[:3].mean(axis=0) + 1e-14  # the fourth corner in the plane of the others
    if order == 2:
        flat[4:] = flat[tet10.EDGES].mean(axis=1)
    coords = np.stack([good, good, inverted, flat])
    with pytest.raises(ValueError, match=r"element 2 .*inverted.*2 such of 4"):
        module.element_stiffness(coords, D)
    with pytest.raises(ValueError, match=r"element 3 .*degenerate"):
        module.check_cells(np.stack([good, good, good, flat]))
    module.check_cells(coords[:2])


@pytest.mark.parametrize("family", FAMILIES)
def test_matrices_equal_scikit_fem(family, rng):
    skfem = pytest.importorskip("skfem")
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    cell_type, order = FAMILIES[family]
    module = ELEMENTS[cell_type]
    nodes, cells = distorted_box(order, rng, cells=(2, 1, 2))
    n = 3 * len(nodes)
    K = assemble(module.element_stiffness(nodes[cells], D), dofs_of(cells), n).toarray()
    M = assemble(module.element_mass(nodes[cells], RHO), dofs_of(cells), n).toarray()

    corner_ids = np.unique(cells[:, :4])
    sk_mesh = skfem.MeshTet(nodes[corner_ids].T, np.searchsorted(corner_ids, cells[:, :4]).T)
    scalar = skfem.ElementTetP1() if order == 1 else skfem.ElementTetP2()
    basis = skfem.Basis(sk_mesh, skfem.ElementVector(scalar), intorder=2 * order)
    K_sk = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis).toarray()

    @skfem.BilinearForm
    def mass(u, v, w):
        return RHO * skfem.helpers.dot(u, v)

    M_sk = skfem.asm(mass, basis).toarray()
    # Map scikit-fem's DOFs onto ours by the location and component of each DOF.
    sk_dofs = [basis.nodal_dofs]
    if order == 2:
        sk_dofs.append(basis.edge_dofs)
    locations = basis.doflocs.T  # (n_sk, 3)
    key = {tuple(np.round(p, 9)): i for i, p in enumerate(nodes)}
    perm = np.empty(n, dtype=int)
    for block in sk_dofs:
        for comp in range(3):
            for d in block[comp]:
                perm[d] = 3 * key[tuple(np.round(locations[d], 9))] + comp
    assert np.unique(perm).size == n
    P = np.zeros((n, n))
    P[np.arange(n), perm] = 1.0
    np.testing.assert_allclose(P @ K @ P.T, K_sk, rtol=0, atol=EXACT_RTOL * np.abs(K_sk).max())
    np.testing.assert_allclose(P @ M @ P.T, M_sk, rtol=0, atol=EXACT_RTOL * np.abs(M_sk).max())
