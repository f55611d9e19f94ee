"""Points between nodes (``fe_core.elements.locate``): the shape-function rows against scikit-fem's
``Basis.probes`` on the same meshes (tet4, tet10 straight and curved, hex8), and fields read exactly."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fe_core.elements.hex8 import NODE_SIGNS
from fe_core.elements.locate import CellLocator
from fe_core.elements.tet10 import EDGES


def _row(loc: CellLocator, point, n: int) -> np.ndarray:
    """The located point's weights as a row over all ``n`` nodes."""
    hit = loc.locate(point)
    row = np.zeros(n)
    np.add.at(row, loc.cells[hit.cell], hit.weights)
    return row


def _interior_points(rng, lo, hi, k=25):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return lo + (hi - lo) * rng.uniform(0.02, 0.98, size=(k, 3))


def _tet_mesh(rng):
    from skfem import MeshTet

    m = MeshTet.init_tensor(np.linspace(0, 1.0, 4), np.linspace(0, 0.5, 3), np.linspace(0, 0.3, 3))
    return m, np.array([0, 0, 0]), np.array([1.0, 0.5, 0.3])


def test_tet4_rows_are_scikit_fems_probes(rng):
    from skfem import Basis, ElementTetP1

    m, lo, hi = _tet_mesh(rng)
    basis = Basis(m, ElementTetP1())
    nodes, cells = m.p.T.copy(), basis.element_dofs.T.copy()   # P1 dofs are the vertices
    loc = CellLocator("tetra", nodes, cells)
    pts = _interior_points(rng, lo, hi)
    P = basis.probes(pts.T).toarray()
    rows = np.array([_row(loc, p, len(nodes)) for p in pts])
    np.testing.assert_allclose(rows, P, rtol=0, atol=1e-10)
    # a linear field is read exactly
    a, B = rng.standard_normal(), rng.standard_normal(3)
    np.testing.assert_allclose(rows @ (a + nodes @ B), a + pts @ B, rtol=0, atol=1e-12)


def test_tet10_rows_are_scikit_fems_probes_and_read_a_quadratic_field(rng):
    from skfem import Basis, ElementTetP2

    m, lo, hi = _tet_mesh(rng)
    basis = Basis(m, ElementTetP2())                    # affine mesh: straight edges, mid-edge dofs at midpoints
    nodes, cells = basis.doflocs.T.copy(), basis.element_dofs.T.copy()
    X = nodes[cells]   # scikit-fem's local order is meshio's tet10 order: corners, edges 01 12 20 03 13 23
    np.testing.assert_allclose(X[:, 4:], 0.5 * (X[:, EDGES[:, 0]] + X[:, EDGES[:, 1]]), atol=1e-14)
    loc = CellLocator("tetra10", nodes, cells)
    pts = _interior_points(rng, lo, hi)
    P = basis.probes(pts.T).toarray()
    rows = np.array([_row(loc, p, len(nodes)) for p in pts])
    np.testing.assert_allclose(rows, P, rtol=0, atol=1e-10)
    C = rng.standard_normal((3, 3))

    def field(x):
        return 0.3 + x @ np.array([1.0, -2.0, 0.5]) + np.einsum("pi,ij,pj->p", x, C, x)

    np.testing.assert_allclose(rows @ field(nodes), field(pts), rtol=0, atol=1e-12)


def _skfem_row(basis, point) -> np.ndarray:
    """scikit-fem's reading at ``point`` on a curved mesh, cell by cell: its own Newton inverse map
    (``mapping.invF``, which does not converge outside a cell, so ``probes`` cannot search) and its basis."""
    x = np.asarray(point, float).reshape(3, 1, 1)
    centres = basis.mesh.doflocs[:, basis.element_dofs].mean(axis=1)   # (3, n_cells): nearest cells first
    for t in np.argsort(np.linalg.norm(centres - x[:, :, 0], axis=0)):
        tind = np.array([t])
        try:
            X = basis.mapping.invF(x, tind=tind)
        except Exception:  # noqa: BLE001 - scikit-fem raises a bare Exception outside the cell
            continue
        xi = X[:, 0, 0]
        if np.abs(basis.mapping.F(X, tind=tind) - x).max() > 1e-12 or min(1 - xi.sum(), *xi) < -1e-12:
            continue
        row = np.zeros(basis.N)
        for k in range(basis.Nbfun):
            row[basis.element_dofs[k, t]] += np.asarray(basis.elem.gbasis(basis.mapping, X, k, tind=tind)[0])[0, 0]
        return row
    raise AssertionError(f"{point} is in no cell")


def test_curved_tet10_rows_by_newton_are_scikit_fems(rng):
    from skfem import Basis, ElementTetP2, MeshTet2

    m, lo, hi = _tet_mesh(rng)
    straight = MeshTet2.from_mesh(m)
    nodes = straight.doflocs.T.copy()
    nv = m.p.shape[1]
    nodes[nv:] += 0.015 * rng.standard_normal((len(nodes) - nv, 3))   # mid-edge nodes off their edges
    curved = replace(straight, doflocs=nodes.T.copy())
    basis = Basis(curved, ElementTetP2())
    cells = basis.element_dofs.T.copy()
    loc = CellLocator("tetra10", nodes, cells)
    pts = _interior_points(rng, lo + 0.05, hi - 0.05, k=8)
    rows = np.array([_row(loc, p, len(nodes)) for p in pts])
    ref = np.array([_skfem_row(basis, p) for p in pts])
    np.testing.assert_allclose(rows, ref, rtol=0, atol=1e-10)
    # the isoparametric map itself: the nodes' coordinates read back the point
    np.testing.assert_allclose(rows @ nodes, pts, rtol=0, atol=1e-12)


def test_hex8_rows_are_scikit_fems_probes_on_a_distorted_mesh(rng):
    from skfem import Basis, ElementHex1, MeshHex

    m = MeshHex.init_tensor(np.linspace(0, 1.0, 4), np.linspace(0, 0.5, 3), np.linspace(0, 0.3, 3))
    p = m.p.copy()
    inner = np.all((p > 1e-9) & (p < np.array([[1.0], [0.5], [0.3]]) - 1e-9), axis=0)
    p[:, inner] += 0.03 * rng.standard_normal((3, int(inner.sum())))   # non-parallelepiped cells
    m = replace(m, doflocs=p)
    basis = Basis(m, ElementHex1())
    # scikit-fem's local node order is not meshio's (VTK's): match the reference corners to hex8.NODE_SIGNS
    signs = 2.0 * ElementHex1.doflocs - 1.0
    perm = [int(np.flatnonzero(np.all(signs == s, axis=1))[0]) for s in NODE_SIGNS]
    nodes, cells = m.p.T.copy(), basis.element_dofs.T[:, perm].copy()
    loc = CellLocator("hexahedron", nodes, cells)
    pts = _interior_points(rng, [0, 0, 0], [1.0, 0.5, 0.3])
    P = basis.probes(pts.T).toarray()
    rows = np.array([_row(loc, q, len(nodes)) for q in pts])
    np.testing.assert_allclose(rows, P, rtol=0, atol=1e-10)
    np.testing.assert_allclose(rows @ nodes, pts, rtol=0, atol=1e-12)   # trilinear map: x read exactly


def test_a_point_at_a_node_and_a_point_a_little_outside(rng):
    from fe_core.tet_mesh import box_tets

    nodes, cells = box_tets((0.2, 0.1, 0.05), (2, 2, 1), order=2)
    loc = CellLocator("tetra10", nodes, cells)
    for n in (0, 7, len(nodes) - 1):
        hit = loc.locate(nodes[n])
        assert hit.outside <= 1e-15 and cells[hit.cell][np.argmax(hit.weights)] == n
        assert np.isclose(hit.weights.max(), 1.0, atol=1e-12) and np.sort(np.abs(hit.weights))[-2] <= 1e-12
    out = np.array([0.21, 0.05, 0.02])            # 1 cm beyond the face x = 0.2
    assert loc.locate(out + [0.1, 0, 0], margin=1e-3) is None   # no cell's box within reach
    hit = loc.locate(out, margin=0.02)
    on_face = hit.weights @ nodes[cells[hit.cell]]
    assert on_face[0] == pytest.approx(0.2, abs=1e-14)   # clipped onto the surface, and reported how far
    assert 0.01 - 1e-12 <= hit.outside <= 0.0125 and hit.outside == pytest.approx(np.linalg.norm(on_face - out))
