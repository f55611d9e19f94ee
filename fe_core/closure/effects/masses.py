"""Added masses: a segment's mass factor (:class:`SegmentMass`), a point mass at a node
(:class:`PointMass`) and the transducers' own mass at every sensor node (:class:`SensorMass`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...assembly import DOFS_PER_NODE
from ...model import ParametricModel
from .base import Effect, Terms, _diag, _NodalEffect, _rows_of, _sensor_nodes

__all__ = ["SegmentMass", "PointMass", "SensorMass", "MASS_SHARE"]


class SegmentMass(Effect):
    """Mass factor of one segment: ``M_s -> M_s (1 + gamma)``."""

    kind = "segment_mass"
    parameters = ("gamma",)
    units = ("-",)
    lower = (-1.0,)
    upper = (10.0,)
    scale = (0.1,)
    margin = (1e-3,)

    def locations(self) -> list[str]:
        return list(self.model.segment_names)

    def terms(self, alpha, location, values) -> Terms:
        s = self.model.segment_names.index(location)
        return Terms(mass=float(values[0]) * self.model.mass_segments.segment(s))

    def describe(self, location) -> dict:
        s = self.model.segment_names.index(location)
        return {"segment": s + 1, "segment_mass_kg": float(self.model.segment_masses[s])}


#: Default plausible share of the structure's mass for an added mass.
MASS_SHARE = 0.2


class PointMass(_NodalEffect):
    """A point mass at a node (translational, on u_x, u_y and u_z); at most :data:`MASS_SHARE` of the model."""

    kind = "point_mass"
    additive = True
    parameters = ("mass",)
    units = ("kg",)
    lower = (0.0,)
    upper = (np.inf,)
    scale = (0.1,)

    def diagonal(self, locations):
        rows = np.array([_rows_of(self.model, self.node(loc)) for loc in locations]).reshape(-1, DOFS_PER_NODE)
        return "mass", np.where(rows >= 0, rows, -1)

    def __init__(self, model: ParametricModel, nodes: Sequence[int] | None = None):
        super().__init__(model, nodes)
        self.upper = (MASS_SHARE * float(model.total_mass()),)

    def terms(self, alpha, location, values) -> Terms:
        rows = _rows_of(self.model, self.node(location))
        rows = rows[rows >= 0]
        return Terms(mass=_diag(self.model.n_dofs, rows, np.full(rows.size, float(values[0]))))


class SensorMass(Effect):
    """The transducers' own mass: one mass at every sensor node, on u_x, u_y and u_z.

    An accelerometer is a rigid point mass, so it loads all three translations
    of its node, not only the measured one. One value for all sensors (they
    are usually alike); the plausible range is up to :data:`MASS_SHARE` of the
    model for all of them together.
    """

    kind = "sensor_mass"
    parameters = ("mass",)
    units = ("kg",)
    lower = (0.0,)
    upper = (np.inf,)
    scale = (0.01,)

    def __init__(self, model: ParametricModel):
        super().__init__(model)
        self.nodes = _sensor_nodes(model)
        self.upper = (MASS_SHARE * float(model.total_mass()) / self.nodes.size,)
        rows = np.concatenate([_rows_of(model, n) for n in self.nodes])
        self._rows = np.unique(rows[rows >= 0])

    def locations(self) -> list[str]:
        return ["all sensors"]

    def diagonal(self, locations):
        return "mass", np.tile(self._rows, (len(locations), 1))

    def terms(self, alpha, location, values) -> Terms:
        return Terms(mass=_diag(self.model.n_dofs, self._rows, np.full(self._rows.size, float(values[0]))))

    def describe(self, location) -> dict:
        return {"nodes": [int(n) for n in self.nodes], "per_sensor": True}


def _sensor_mass_factory(model: ParametricModel) -> SensorMass | None:
    """The transducers' mass, or None where no sensor reads a DOF of a node the model holds (nothing to load)."""
    effect = SensorMass(model)
    return effect if effect._rows.size else None
