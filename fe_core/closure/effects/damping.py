"""Damping: :class:`RayleighDamping`, a change of one Rayleigh coefficient (``a`` or ``b``)."""

from __future__ import annotations

import numpy as np

from ...model import ParametricModel
from .base import Effect, Terms

__all__ = ["RayleighDamping"]


class RayleighDamping(Effect):
    """A change of one Rayleigh coefficient: location ``a`` (1/s) or ``b`` (s)."""

    kind = "damping"
    parameters = ("delta",)
    units = ("1/s or s",)
    lower = (-np.inf,)
    upper = (np.inf,)
    scale = (1.0,)

    def __init__(self, model: ParametricModel):
        super().__init__(model)
        a, b = model.damping
        self._base = {"a": a, "b": b}

    def locations(self) -> list[str]:
        return ["a", "b"]

    def scale_at(self, location: str) -> np.ndarray:
        # About the change that moves the damping ratio of a ~100 Hz mode by 1 %.
        return np.array([10.0 if location == "a" else 2e-5])

    def bounds_at(self, location: str) -> tuple[np.ndarray, np.ndarray]:
        """The coefficient may drop to zero, not below."""
        return np.array([-self._base[location]]), np.array([np.inf])

    def check(self, location, values):
        if location not in ("a", "b"):
            raise ValueError(f"effect 'damping' has no location {location!r}; choose 'a' or 'b'")
        v = np.atleast_1d(np.asarray(values, dtype=float))
        if v.shape != (1,) or not np.isfinite(v[0]):
            raise ValueError(f"effect 'damping' at {location}: one finite value expected, got {values!r}")
        if self._base[location] + v[0] < 0:
            raise ValueError(f"effect 'damping' at {location}: {location} = {self._base[location] + v[0]} "
                             f"would be negative")
        return v

    def terms(self, alpha, location, values) -> Terms:
        if location == "a":
            return Terms(damping_a=float(values[0]))
        return Terms(damping_b=float(values[0]))

    def describe(self, location) -> dict:
        return {"coefficient": location, "base_value": self._base[location],
                "unit": "1/s" if location == "a" else "s"}
