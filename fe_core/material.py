"""Isotropic linear elasticity."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Material", "isotropic_elasticity"]


def isotropic_elasticity(E: float, nu: float) -> np.ndarray:
    """Full 3-D elasticity matrix (no plane-stress reduction).

    Parameters
    ----------
    E : float, Pa
        Young's modulus, positive.
    nu : float
        Poisson's ratio, in (-1, 0.5).

    Returns
    -------
    ndarray, shape (6, 6), Pa
        For the engineering strain order ``[exx, eyy, ezz, gxy, gyz, gzx]``.
    """
    if not E > 0.0:
        raise ValueError(f"Young's modulus must be positive, got E = {E}")
    if not -1.0 < nu < 0.5:
        raise ValueError(f"Poisson's ratio must lie in (-1, 0.5), got nu = {nu}")
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    mu = E / (2.0 * (1.0 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.arange(3), np.arange(3)] += 2.0 * mu
    D[np.arange(3, 6), np.arange(3, 6)] = mu
    return D


@dataclass(frozen=True)
class Material:
    """An isotropic linear-elastic material.

    Attributes
    ----------
    E : float, Pa
    nu : float
    rho : float, kg/m^3
    """

    E: float
    nu: float
    rho: float

    def __post_init__(self) -> None:
        isotropic_elasticity(self.E, self.nu)  # validates E and nu
        if not self.rho > 0.0:
            raise ValueError(f"density must be positive, got rho = {self.rho}")

    @property
    def D(self) -> np.ndarray:
        """Elasticity matrix, shape (6, 6), Pa."""
        return isotropic_elasticity(self.E, self.nu)
