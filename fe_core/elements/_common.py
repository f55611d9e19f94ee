"""What every element family shares: the check that refuses inverted and degenerate cells."""

from __future__ import annotations

import numpy as np

__all__ = ["DEGENERATE_RTOL", "check_jacobians"]

#: A cell whose smallest Jacobian determinant is at most this fraction of the cube of
#: its diameter (largest node-to-node distance) counts as degenerate: a flat cell
#: computed in floating point has det J of order 1e-16 diameter^3, not exactly 0,
#: while a regular tetrahedron has 6 V / L^3 = 0.71 and a cube 8 det J / (sqrt(3) L)^3
#: = 0.19 on its reference cell of volume 8.
DEGENERATE_RTOL = 1e-10


def check_jacobians(detJ: np.ndarray, coords: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first cell with a non-positive (or degenerate) det J.

    Parameters
    ----------
    detJ : ndarray, shape (n_elements, n_points)
        Jacobian determinants at the points where the family checks them.
    coords : ndarray, shape (n_elements, n_nodes, 3), m
    """
    coords = np.asarray(coords, dtype=float)
    differences = coords[:, :, None, :] - coords[:, None, :, :]
    scale = np.sqrt((differences**2).sum(axis=-1)).max(axis=(1, 2)) ** 3
    bad = np.any(detJ <= DEGENERATE_RTOL * scale[:, None], axis=1)
    if np.any(bad):
        first = int(np.flatnonzero(bad)[0])
        kind = "inverted" if np.any(detJ[first] < 0.0) else "degenerate"
        raise ValueError(
            f"element {first} has a non-positive Jacobian ({kind} cell; {int(bad.sum())} such "
            f"of {len(bad)}): min det J = {detJ[first].min():.3e} at diameter "
            f"{scale[first] ** (1 / 3):.3e}"
        )
