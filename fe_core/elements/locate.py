"""Points inside a mesh: the cell holding a point, its natural coordinates there (the inverse isoparametric
map) and the cell's shape functions at it.

A sensor or a hammer rarely sits on a node of a solid mesh; through the element's shape functions the
displacement at the point is ``u(p) = sum_a N_a(xi) u_a``, and a point force there has the consistent nodal
forces ``F_a = N_a(xi) f`` (the same weights, exact in virtual work).

The inverse map solves ``x(xi) = sum_a N_a(xi) x_a = p`` by Newton's method on the natural coordinates,
each family with its own shape functions (:mod:`.tet4`, :mod:`.tet10`, :mod:`.hex8`):

* tetrahedra start from the affine map of the four corners (exact for tet4 and for tet10 with straight
  edges, which then converge in one step; curved tet10 edges take a few);
* hexahedra start from the centre ``xi = 0``.

Cells are candidates when their nodes' bounding box, widened by the tolerance and a tenth of the box (a
curved tet10 edge may bulge past its nodes), holds the point. A point in no cell (on the surface up to
rounding, or a little outside) goes to the candidate whose clipped natural point (the coordinates projected
onto the reference cell) lies nearest to it; the caller decides whether that distance is acceptable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import element_family

__all__ = ["PointLocation", "CellLocator", "INSIDE_RTOL"]

#: Natural coordinates this far outside the reference cell (barycentric below ``-INSIDE_RTOL``, ``|xi|``
#: above ``1 + INSIDE_RTOL``) still count as inside: a point on a shared face, up to rounding.
INSIDE_RTOL = 1e-10

#: Reference cell of each meshio cell type: the unit tetrahedron or the cube [-1, 1]^3.
_REFERENCE = {"tetra": "simplex", "tetra10": "simplex", "hexahedron": "cube"}

_NEWTON_STEPS = 50
_NEWTON_TOL = 1e-14
#: Cells scanned at a time for the bounding boxes (memory ~ 240 B a tet10 cell).
_CHUNK = 200_000


@dataclass(frozen=True)
class PointLocation:
    """Where a point lies in a mesh.

    Attributes
    ----------
    cell : int
        Index of the cell (row of the mesh's ``cells``).
    xi : ndarray, shape (3,)
        Natural coordinates in the cell's reference element (clipped onto it for a point outside).
    weights : ndarray, shape (nodes per cell,)
        The cell's shape functions ``N_a(xi)``, in the cell's node order (sum 1).
    outside : float
        Distance from the point to ``x(xi)`` (0 up to rounding for a point inside), in the mesh's units.
    """

    cell: int
    xi: np.ndarray
    weights: np.ndarray
    outside: float


def _simplex_projection(L: np.ndarray) -> np.ndarray:
    """Euclidean projection of rows of barycentric coordinates onto ``{L >= 0, sum L = 1}``, shape (c, 4)."""
    u = -np.sort(-L, axis=1)
    css = np.cumsum(u, axis=1) - 1.0
    k = np.arange(1, L.shape[1] + 1)
    rho = np.sum(u - css / k > 0, axis=1)
    theta = css[np.arange(L.shape[0]), rho - 1] / rho
    return np.maximum(L - theta[:, None], 0.0)


class CellLocator:
    """Finds the cell and natural coordinates of points in one mesh (cell type of :mod:`fe_core.elements`).

    Parameters
    ----------
    cell_type : str
        meshio cell type: ``"tetra"``, ``"tetra10"`` or ``"hexahedron"``.
    nodes : ndarray, shape (n_nodes, 3)
    cells : ndarray, shape (n_cells, nodes per cell), int
        In meshio's (VTK's) node order, as the element families expect.
    """

    def __init__(self, cell_type: str, nodes: np.ndarray, cells: np.ndarray):
        if cell_type not in _REFERENCE:
            raise ValueError(f"no point location for cell type {cell_type!r}; supported: "
                             f"{', '.join(sorted(_REFERENCE))}")
        self.cell_type = cell_type
        self.family = element_family(cell_type)
        self.reference = _REFERENCE[cell_type]
        self.nodes = np.asarray(nodes, dtype=float)
        self.cells = np.asarray(cells)
        lo, hi = [], []
        for start in range(0, len(self.cells), _CHUNK):
            xyz = self.nodes[self.cells[start:start + _CHUNK]]
            lo.append(xyz.min(axis=1))
            hi.append(xyz.max(axis=1))
        self._lo = np.concatenate(lo) if lo else np.zeros((0, 3))
        self._hi = np.concatenate(hi) if hi else np.zeros((0, 3))

    # -- the reference cell -------------------------------------------------------------------------
    def _start(self, X: np.ndarray, p: np.ndarray) -> np.ndarray:
        """First natural coordinates, shape (c, 3): the corners' affine map (tetrahedra), the centre (hex)."""
        if self.reference == "cube":
            return np.zeros((X.shape[0], 3))
        A = (X[:, 1:4] - X[:, :1]).transpose(0, 2, 1)   # columns: edges 01, 02, 03
        return np.linalg.solve(A, (p - X[:, 0])[:, :, None])[:, :, 0]

    def _inside_margin(self, xi: np.ndarray) -> np.ndarray:
        """How far inside the reference cell, shape (c,): min barycentric (simplex), 1 - max |xi| (cube)."""
        if self.reference == "cube":
            return 1.0 - np.abs(xi).max(axis=1)
        return np.column_stack([1.0 - xi.sum(axis=1), xi]).min(axis=1)

    def _clip(self, xi: np.ndarray) -> np.ndarray:
        """Natural coordinates moved onto the reference cell, shape (c, 3)."""
        if self.reference == "cube":
            return np.clip(xi, -1.0, 1.0)
        return _simplex_projection(np.column_stack([1.0 - xi.sum(axis=1), xi]))[:, 1:]

    def _bound(self, xi: np.ndarray) -> np.ndarray:
        """Keep Newton's iterates of a point far outside a cell from running away (3 cell sizes)."""
        return np.clip(xi, -3.0, 3.0) if self.reference == "cube" else np.clip(xi, -3.0, 4.0)

    # -- the map ---------------------------------------------------------------------------------------
    def _map(self, X: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """``x(xi)`` of each candidate cell, shape (c, 3)."""
        return np.einsum("ca,caj->cj", self.family.shape_functions(xi), X)

    def _newton(self, X: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Natural coordinates with ``x(xi) = p`` in each candidate cell (extrapolated outside it), (c, 3)."""
        xi = self._start(X, p)
        for _ in range(_NEWTON_STEPS):
            dN = self.family.shape_gradients(xi)                     # (c, a, 3)
            A = np.einsum("caj,cai->cji", X, dN)                      # dx_j / dxi_i
            r = p - self._map(X, xi)
            ok = np.abs(np.linalg.det(A)) > 1e-300
            step = np.zeros_like(xi)
            if ok.any():
                step[ok] = np.linalg.solve(A[ok], r[ok][:, :, None])[:, :, 0]
            xi = self._bound(xi + step)
            if np.max(np.abs(step), initial=0.0) <= _NEWTON_TOL:
                break
        return xi

    def candidates(self, point: np.ndarray, margin: float) -> np.ndarray:
        """Cells whose nodes' bounding box, widened by ``margin`` and a tenth of its size, holds the point."""
        pad = margin + 0.1 * (self._hi - self._lo).max(axis=1, keepdims=True)
        return np.flatnonzero(np.all((self._lo - pad <= point) & (point <= self._hi + pad), axis=1))

    def locate(self, point, margin: float = 0.0) -> PointLocation | None:
        """The cell holding ``point``, or the one whose clipped natural point is nearest to it.

        Parameters
        ----------
        point : array_like, shape (3,)
        margin : float
            Cells up to this far from the point (mesh units) are searched when it lies in none.

        Returns
        -------
        PointLocation or None
            None when no cell's bounding box comes within ``margin`` of the point.
        """
        p = np.asarray(point, dtype=float)
        cand = self.candidates(p, margin)
        if cand.size == 0:
            return None
        X = self.nodes[self.cells[cand]]
        xi = self._newton(X, p)
        inside = self._inside_margin(xi)
        converged = np.linalg.norm(self._map(X, xi) - p, axis=1) <= 1e-9 * max(1.0, float(np.abs(X).max()))
        good = converged & (inside >= -INSIDE_RTOL)
        if good.any():
            k = int(np.flatnonzero(good)[np.argmax(inside[good])])
            xi_k = xi[k]
        else:   # a little outside: the nearest clipped natural point (clip and recompute)
            clipped = self._clip(xi)
            dist = np.linalg.norm(self._map(X, clipped) - p, axis=1)
            k = int(np.argmin(dist))
            xi_k = clipped[k]
        weights = self.family.shape_functions(xi_k[None])[0]
        outside = float(np.linalg.norm(weights @ X[k] - p))
        return PointLocation(int(cand[k]), xi_k.copy(), weights, outside)
