"""What every trainer returns, and the bounds handling they share."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Result", "check_bounds", "check_options"]


@dataclass(frozen=True)
class Result:
    """Outcome of a minimisation.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Best point found (inside the bounds).
    fun : float
        Objective at ``x``.
    nfev : int
        Objective evaluations spent.
    nit : int
        Iterations (temperature levels, swarm generations, or L-BFGS-B
        iterations summed over starts).
    message : str
    history : ndarray, shape (nit,)
        Best objective value after each iteration (for diagnostics and tests).
    """

    x: np.ndarray
    fun: float
    nfev: int
    nit: int
    message: str
    history: np.ndarray = field(default_factory=lambda: np.empty(0))


def check_bounds(bounds) -> tuple[np.ndarray, np.ndarray]:
    """Validate a box.

    Parameters
    ----------
    bounds : array_like, shape (n, 2)
        ``[(low, high), ...]``, finite, ``low <= high``.

    Returns
    -------
    low, high : ndarray, shape (n,)
    """
    b = np.asarray(bounds, dtype=float)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] == 0:
        raise ValueError(f"bounds must have shape (n, 2), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b[:, 0] > b[:, 1]):
        raise ValueError(f"bounds must be finite with low <= high, got {b.tolist()}")
    return b[:, 0].copy(), b[:, 1].copy()


def check_options(options: dict | None, defaults: dict, trainer: str) -> dict:
    """Merge ``options`` into ``defaults``, refusing unknown keys."""
    options = dict(options or {})
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise ValueError(f"unknown {trainer} option(s) {unknown}; valid options are {sorted(defaults)}")
    return {**defaults, **options}
