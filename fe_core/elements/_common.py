"""What every element family shares: the check that refuses inverted and degenerate cells."""

from __future__ import annotations

import numpy as np

__all__ = ["DEGENERATE_RTOL", "check_jacobians"]

#: A cell whose smallest Jacobian determinant is at most this fraction of the cube of
#: its size (the diagonal of its nodes' bounding box) counts as degenerate: a flat cell
#: computed in floating point has det J of order 1e-16 size^3, not exactly 0, while a
#: regular tetrahedron has det J / size^3 = 0.39 and a cube 0.024 (det J of the
#: reference cube of volume 8).
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
    scale = np.linalg.norm(np.ptp(coords, axis=1), axis=1) ** 3
    bad = np.any(detJ <= DEGENERATE_RTOL * scale[:, None], axis=1)
    if np.any(bad):
        first = int(np.flatnonzero(bad)[0])
        kind = "inverted" if np.any(detJ[first] < 0.0) else "degenerate"
        raise ValueError(
            f"element {first} has a non-positive Jacobian ({kind} cell; {int(bad.sum())} such "
            f"of {len(bad)}): min det J = {detJ[first].min():.3e} at size "
            f"{scale[first] ** (1 / 3):.3e}"
        )
