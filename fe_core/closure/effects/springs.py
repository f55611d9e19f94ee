"""Springs to ground: :class:`GroundedSpring`, a translational spring from a node to ground along one axis."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...model import ParametricModel
from .base import Terms, _diag, _NodalEffect, _rows_of, candidate_nodes

__all__ = ["GroundedSpring"]


class GroundedSpring(_NodalEffect):
    """A translational spring from a node to ground, along one axis (u_z by default)."""

    kind = "grounded_spring"
    additive = True
    parameters = ("k",)
    units = ("N/m",)
    lower = (0.0,)
    upper = (1e8,)
    scale = (1e5,)
    #: Fitted in ln(k) (:func:`fe_core.closure.fits.log_sized`): soft to nearly rigid is one search.
    log_sizes = (True,)
    component = 2

    def __init__(self, model: ParametricModel, nodes: Sequence[int] | None = None, component: int | None = None):
        if component is not None:
            if component not in (0, 1, 2):
                raise ValueError(f"grounded spring direction must be 0, 1 or 2 (x, y, z), got {component!r}")
            self.component = component
        super().__init__(model, nodes)

    def _candidates(self) -> np.ndarray:
        return candidate_nodes(self.model, self.node_set, self.component)

    def diagonal(self, locations):
        rows = np.array([_rows_of(self.model, self.node(loc))[self.component] for loc in locations]).reshape(-1, 1)
        return "stiffness", np.where(rows >= 0, rows, -1)

    def terms(self, alpha, location, values) -> Terms:
        row = _rows_of(self.model, self.node(location))[self.component]
        return Terms(stiffness=_diag(self.model.n_dofs, np.array([row]), np.array([float(values[0])])))
