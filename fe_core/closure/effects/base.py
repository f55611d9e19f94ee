"""The effect machinery: :class:`Terms`, the :class:`Effect` base, :class:`Applied`, the node helpers the
built-in effects share (free-DOF rows of nodes, candidate nodes, sensor nodes, nodal placement) and the
registry (:func:`register_effect`, :func:`build_library`).

The built-in effects register themselves in :mod:`fe_core.closure.effects` (the package), in the order
that decides ties and output order.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ...assembly import DOFS_PER_NODE
from ...model import ParametricModel

__all__ = [
    "Terms",
    "Effect",
    "Applied",
    "node_rows",
    "candidate_nodes",
    "EffectFactory",
    "register_effect",
    "unregister_effect",
    "registered_effects",
    "build_library",
]


@dataclass(frozen=True)
class Terms:
    """Additions to a model at given effect parameter values.

    Attributes
    ----------
    stiffness : sparse (n_free, n_free) or None, N/m
    mass : sparse (n_free, n_free) or None, kg
    damping_a : float, 1/s
        Added to the mass-proportional Rayleigh coefficient.
    damping_b : float, s
        Added to the stiffness-proportional Rayleigh coefficient.
    """

    stiffness: sp.spmatrix | None = None
    mass: sp.spmatrix | None = None
    damping_a: float = 0.0
    damping_b: float = 0.0
    #: Relative amplitude factors per sensor, shape (n_sensors,): the compared amplitude is
    #: ``|Z_s| (1 + gain_s)`` (a calibration error; it changes the comparison, not the structure).
    gain: np.ndarray | None = None


class Effect(abc.ABC):
    """One kind of effect with its candidate locations.

    Subclasses set the class attributes and implement :meth:`locations` and
    :meth:`terms`. Instances are built for one model.

    Attributes
    ----------
    kind : str
        Registry name, e.g. ``"point_mass"``.
    parameters : tuple of str
        Parameter names at one location.
    units : tuple of str
    lower, upper : tuple of float
        Bounds of each parameter; a bound that the physics excludes (a factor
        of exactly -1) is kept off by :attr:`margin` in fits.
    scale : tuple of float
        Typical magnitude of each parameter (scales fits and reports).
    """

    kind: str = ""
    parameters: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    lower: tuple[float, ...] = ()
    upper: tuple[float, ...] = ()
    scale: tuple[float, ...] = ()
    #: Bounds that must be strictly avoided (factor > -1) are moved inward by this much.
    margin: tuple[float, ...] = ()
    #: One value that adds up when two lie at one place (a mass, a spring to ground along an axis): two found close
    #: together are one between nodes (:func:`fe_core.closure.identify.combined`).
    additive: bool = False

    def __init__(self, model: ParametricModel):
        self.model = model

    @property
    def n_parameters(self) -> int:
        return len(self.parameters)

    @abc.abstractmethod
    def locations(self) -> list[str]:
        """Candidate location labels, unique within this effect."""

    @abc.abstractmethod
    def terms(self, alpha: np.ndarray, location: str, values: np.ndarray) -> Terms:
        """The additions at ``values`` (shape (n_parameters,)), linear in ``values``."""

    def derivative(self, alpha: np.ndarray, location: str, index: int) -> Terms:
        """Derivative of the terms with respect to parameter ``index`` (terms at a unit value)."""
        unit = np.zeros(self.n_parameters)
        unit[index] = 1.0
        return self.terms(alpha, location, unit)

    def alpha_derivative(self, alpha: np.ndarray, location: str, values: np.ndarray, index: int) -> Terms | None:
        """Derivative of the terms with respect to ``alpha[index]``; None if they do not depend on alpha."""
        return None

    def describe(self, location: str) -> dict:
        """Extra facts about a location for reports (coordinates, cells...)."""
        return {}

    def position(self, location: str) -> np.ndarray | None:
        """Where a location is, shape (3,), m (a node, a band's centroid); None if it has no place."""
        return None

    def diagonal(self, locations: Sequence[str]) -> tuple[str, np.ndarray] | None:
        """For a one-parameter effect whose unit terms are ones on a few diagonal entries of K or M:
        ``("stiffness" | "mass", rows)`` with ``rows`` (len(locations), k) free-DOF indices, -1 padded
        (the screening then derives every location in one product); None otherwise."""
        return None

    def neighbours(self, location: str) -> list[str]:
        """Locations next to ``location`` (used to refine a searched location); none by default."""
        return []

    def set_limits(self, lower=None, upper=None) -> "Effect":
        """Set the plausible range (the fit box) of every parameter; returns the effect."""
        if lower is not None:
            self.lower = tuple(np.broadcast_to(np.asarray(lower, float), (self.n_parameters,)))
        if upper is not None:
            self.upper = tuple(np.broadcast_to(np.asarray(upper, float), (self.n_parameters,)))
        if any(lo >= hi for lo, hi in zip(self.lower, self.upper)):
            raise ValueError(f"effect {self.kind!r}: lower limits {self.lower} must be below upper {self.upper}")
        return self

    def bounds_at(self, location: str) -> tuple[np.ndarray, np.ndarray]:
        """Bounds for a least-squares fit at a location (the plausible range), excluded edges moved inward."""
        lo = np.array(self.lower, float)
        hi = np.array(self.upper, float)
        if self.margin:
            lo = lo + np.array(self.margin, float)
        return lo, hi

    def scale_at(self, location: str) -> np.ndarray:
        """Typical magnitude of each parameter at a location (scales fits)."""
        return np.array(self.scale, float)

    def check(self, location: str, values) -> np.ndarray:
        """Validate a location and values; returns the values as an array."""
        if location not in self._location_set():
            raise ValueError(f"effect {self.kind!r} has no location {location!r}")
        v = np.atleast_1d(np.asarray(values, dtype=float))
        if v.shape != (self.n_parameters,):
            raise ValueError(f"effect {self.kind!r} takes {self.n_parameters} parameter(s) "
                             f"{self.parameters}, got shape {v.shape}")
        for name, x, lo, hi, unit in zip(self.parameters, v, self.lower, self.upper, self.units):
            strict = bool(self.margin)
            if not np.isfinite(x) or x < lo or x > hi or (strict and x <= lo):
                raise ValueError(f"effect {self.kind!r} at {location}: {name} = {x} {unit} is outside "
                                 f"its valid range {'(' if strict else '['}{lo}, {hi}]")
        return v

    def _location_set(self) -> set:
        cached = getattr(self, "_locset", None)
        if cached is None:
            cached = self._locset = set(self.locations())
        return cached


@dataclass(frozen=True)
class Applied:
    """An effect at one location with parameter values."""

    effect: Effect
    location: str
    values: np.ndarray = field(default_factory=lambda: np.zeros(1))

    def terms(self, alpha) -> Terms:
        return self.effect.terms(alpha, self.location, self.effect.check(self.location, self.values))

    def label(self) -> str:
        return f"{self.effect.kind} at {self.location}"


# -- helpers ------------------------------------------------------------------------------------------
def _free_position(model: ParametricModel) -> np.ndarray:
    """Free-DOF index of every DOF before constraints (-1 on a constrained DOF), shape (n_total_dofs,)."""
    pos = getattr(model, "_free_position_cache", None)
    if pos is None:
        pos = np.full(model.n_total_dofs, -1)
        pos[model.free_dofs] = np.arange(model.free_dofs.size)
        model._free_position_cache = pos
    return pos


def node_rows(model: ParametricModel) -> tuple[np.ndarray, np.ndarray]:
    """Every node's translational DOFs on the free DOFs, for a mesh or a matrices model.

    Returns
    -------
    nodes : ndarray, shape (k,), int
        Node ids (0-based mesh nodes, or the ids of a matrices model's DOF table).
    rows : ndarray, shape (k, 3), int
        Free-DOF index of u_x, u_y, u_z of each node; -1 where the DOF is
        constrained, -2 where a matrices model has no such DOF.
    """
    cached = getattr(model, "_node_rows_cache", None)
    if cached is None:
        pos = _free_position(model)
        if model.dof_table is None:
            nodes = np.arange(model.n_total_dofs // DOFS_PER_NODE)
            rows = pos[DOFS_PER_NODE * nodes[:, None] + np.arange(DOFS_PER_NODE)]
        else:
            table = np.asarray(model.dof_table)
            nodes, which = np.unique(table[:, 0], return_inverse=True)
            rows = np.full((nodes.size, DOFS_PER_NODE), -2)
            rows[which, table[:, 1]] = pos
        cached = model._node_rows_cache = (nodes, rows, {int(n): i for i, n in enumerate(nodes)})
    return cached[0], cached[1]


def _rows_of(model: ParametricModel, node: int) -> np.ndarray:
    """Free-DOF index of u_x, u_y, u_z of one node (negative if constrained or absent), shape (3,)."""
    _, rows = node_rows(model)
    i = model._node_rows_cache[2].get(int(node))
    return rows[i] if i is not None else np.full(DOFS_PER_NODE, -2)  # a node the model's DOFs do not name


def candidate_nodes(model: ParametricModel, node_set: str = "top", component: int | None = None) -> np.ndarray:
    """Nodes of a named set whose DOFs are all free (all such nodes if the set or the mesh is absent);
    with ``component``, the nodes whose DOF along that axis is free. A matrices model with a node table offers
    only the nodes the table places: a solver's own nodes (CalculiX's expanded shell and beam nodes) are not the
    structure's, and a few milligrams on one of them moved a mode of issue 40's channel deck by 2 %."""
    nodes, rows = node_rows(model)
    if model.mesh is not None and node_set in model.mesh.node_sets:
        pick = np.asarray(model.mesh.node_sets[node_set])
        nodes, rows = nodes[pick], rows[pick]
    elif model.mesh is None and model.node_coordinates is not None:  # aligned with node_rows' nodes
        placed = np.all(np.isfinite(np.asarray(model.node_coordinates, float)), axis=1)
        if placed.size == nodes.size and placed.any():
            nodes, rows = nodes[placed], rows[placed]
    if component is not None:
        return nodes[rows[:, component] >= 0]
    # Every DOF the node has is free (a matrices model may lack some translations: -2).
    return nodes[np.all(rows != -1, axis=1) & np.any(rows >= 0, axis=1)]


def _diag(n: int, rows: np.ndarray, values: np.ndarray) -> sp.csr_matrix:
    return sp.csr_matrix((values, (rows, rows)), shape=(n, n))


class _NodalEffect(Effect):
    """Base of effects placed at one node chosen among candidate nodes."""

    node_set = "top"

    def __init__(self, model: ParametricModel, nodes: Sequence[int] | None = None):
        super().__init__(model)
        self.nodes = np.asarray(self._candidates() if nodes is None else nodes, dtype=int)
        self._index = {f"node {n}": int(n) for n in self.nodes}

    def _candidates(self) -> np.ndarray:
        return candidate_nodes(self.model, self.node_set)

    def locations(self) -> list[str]:
        return list(self._index)

    def node(self, location: str) -> int:
        try:
            return self._index[location]
        except KeyError:
            raise ValueError(f"effect {self.kind!r} has no location {location!r}") from None

    def describe(self, location) -> dict:
        n = self.node(location)
        p = self.model.node_position(n)
        if p is None:  # a matrices model without a node table: no coordinates
            return {"node": n}
        x, y, z = p
        return {"node": n, "x_m": float(x), "y_m": float(y), "z_m": float(z)}

    def position(self, location) -> np.ndarray | None:
        return self.model.node_position(self.node(location))

    def neighbours(self, location) -> list[str]:
        """Candidate nodes sharing a cell with this node (without a mesh: coupled to it in K)."""
        n = self.node(location)
        if self.model.mesh is not None:
            cells = self.model.mesh.cells
            near = np.unique(cells[np.any(cells == n, axis=1)])
        else:
            rows = _rows_of(self.model, n)
            coupled = np.unique(self.model.stiffness_segments.pattern[rows[rows >= 0]].indices)
            nodes, all_rows = node_rows(self.model)
            near = nodes[np.any(np.isin(all_rows, coupled), axis=1)]
        return [f"node {m}" for m in near if m != n and f"node {m}" in self._index]


def _sensor_nodes(model: ParametricModel) -> np.ndarray:
    """Node of each sensor, shape (n_sensors,)."""
    nodes = getattr(model, "sensor_nodes", None)
    if nodes is not None:
        return np.asarray(nodes, dtype=int)
    # The node of the DOFs each output vector reads: a sensor along a vector reads one node's DOFs; on a solver's
    # shell deck it may read the mean of the expanded nodes through the thickness, of which the node table holds
    # only the shell's own (CalculiX: issue 40's channel deck), so the first DOF read that a node owns counts.
    L = model.outputs.tocsc()
    all_nodes, rows = node_rows(model)
    owner = np.full(model.n_dofs, -1)
    for c in range(DOFS_PER_NODE):
        ok = rows[:, c] >= 0
        owner[rows[ok, c]] = all_nodes[ok]
    out = np.full(L.shape[1], -1)
    for j in range(L.shape[1]):
        owned = owner[L.indices[L.indptr[j]:L.indptr[j + 1]]]
        owned = owned[owned >= 0]
        if owned.size:
            out[j] = owned[0]
    return out


# -- registry -----------------------------------------------------------------------------------------
EffectFactory = Callable[[ParametricModel], "Effect | None"]
_REGISTRY: dict[str, EffectFactory] = {}


def register_effect(name: str, factory: EffectFactory | None = None, *, replace: bool = False):
    """Register an effect factory ``factory(model) -> Effect or None`` under ``name``.

    A factory returns None when the effect does not apply to a model (no
    joints, say). Usable as a decorator: ``@register_effect("mine")``.
    """
    def add(f: EffectFactory) -> EffectFactory:
        if name in _REGISTRY and not replace:
            raise ValueError(f"an effect named {name!r} is already registered (pass replace=True)")
        _REGISTRY[name] = f
        return f

    return add if factory is None else add(factory)


def unregister_effect(name: str) -> None:
    if name not in _REGISTRY:
        raise KeyError(f"no effect named {name!r} is registered")
    del _REGISTRY[name]


def registered_effects() -> list[str]:
    return list(_REGISTRY)


def build_library(model: ParametricModel, names: Sequence[str] | None = None) -> list[Effect]:
    """Instantiate the registered effects (all, or ``names`` in that order) for a model.

    Effects that do not apply to the model (a patch on a model given as matrices) are left out of
    the default library; named explicitly they are refused with ``ValueError`` saying what they need.
    """
    explicit = names is not None
    names = registered_effects() if names is None else list(names)
    out = []
    for name in names:
        if name not in _REGISTRY:
            raise ValueError(f"unknown effect {name!r}; registered: {', '.join(registered_effects())}")
        effect = _REGISTRY[name](model)
        if effect is None and explicit:
            needs = _NEEDS.get(name, "what its factory looks for")
            raise ValueError(f"effect {name!r} does not apply to the model {model.source or ''}".rstrip()
                             + f": it needs {needs}")
        if effect is not None:
            if effect.kind != name:
                effect.kind = name
            out.append(effect)
    return out


#: What the built-in effects that do not apply to every model need (for the refusal's message).
_NEEDS = {
    "patch": "a mesh whose element matrices the model gives (not a model given as matrices)",
    "cell_set": "a mesh with element matrices and a named cell set that is not a union of whole segments",
    "joint_band": "a mesh with element matrices and cell sets plate1, plate2, ... meeting at planes x = const",
    "sensor_mass": "sensors that read the DOFs of nodes the model holds",
}
