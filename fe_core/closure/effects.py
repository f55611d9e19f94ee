"""Candidate effects a model may lack, as small parametric extensions of the FE model.

Measured structures carry effects that no updating parameter represents: an
added mass (a sensor, a bolt), a flexible support, a weakened joint, other
damping. Each :class:`Effect` here is one such extension. It has a list of
candidate *locations* (a node, a segment, a joint, a damping coefficient)
and, at each location, a few real parameters; at given parameter values it
returns :class:`Terms`: sparse additions to the stiffness and mass matrices
on the free DOFs and additions to the Rayleigh coefficients ``(a, b)``.

Terms are **linear in the parameters** (all effects here are, and a user
effect must be, or override :meth:`Effect.derivative`), so the derivative of
the dynamic stiffness with respect to a parameter is the terms at a unit
value. That is what makes the linearised screening of
:class:`LinearisedResponse` exact to first order and cheap.

Built-in effects (registered under these names, see :func:`build_library`):

==================  =====================================  ===========  ==================
name                location                               parameter    unit
==================  =====================================  ===========  ==================
``segment_mass``    a segment (``segment3``)               ``gamma``    - (M_s (1 + gamma))
``point_mass``      a node (``node 512``)                  ``mass``     kg, on u_x, u_y, u_z
``grounded_spring`` a node                                 ``k``        N/m, on u_z to ground
``joint_band``      a plate joint (``joint x=230 mm``)     ``beta``     - (band K (1 + beta))
``damping``         ``a`` or ``b``                         ``delta``    1/s or s, added
``grounded_spring_x``, ``_y``  a node                      ``k``        N/m, on u_x / u_y
``sensor_mass``     ``all sensors``                        ``mass``     kg at every sensor node
``sensor_gain``     a sensor (``sensor 3``)                ``g``        - (|Z_s| (1 + g))
``patch``           cells within 1 or 2 rings of a node    ``beta``     - (patch K (1 + beta))
``cell_set``        a named cell set (``set right``)       ``beta``     - (set K (1 + beta))
==================  =====================================  ===========  ==================

Any model: nodes and their DOFs come from the mesh or, for a model given as
matrices, from its DOF table (:func:`node_rows`); the cell effects (``patch``,
``cell_set``, ``joint_band``) need a mesh and its element matrices
(``ParametricModel.cell_stiffness``) and are left out elsewhere (refused when
named, :func:`build_library`).

Plausibility: every effect's fit box (:meth:`Effect.bounds_at`) is its
*plausible* range, which a user may narrow or widen per kind with
:meth:`Effect.set_limits`. Defaults: a point mass at most 20 % of the
structure's mass, the sensor masses together at most 20 %, a grounded spring
at most 1e8 N/m, a sensor gain within +-50 %, factors above -1 (kept off by a
margin), a band's or patch's stiffness at most doubled (+1), a segment's mass
factor at most 10. A fit that ends on such a bound is not a finding
(:func:`fe_core.closure.at_bound`).

Every extension keeps K symmetric positive definite and M positive definite
within the parameter bounds (springs and masses are non-negative, factors
stay above -1), so the Krylov FRF of :mod:`fe_core.solvers.frf` (banded Cholesky of
K) applies unchanged and an extended model costs what the base model costs.

Users add their own effect with :func:`register_effect`::

    from fe_core.closure.effects import Effect, Terms, register_effect

    class TipSpring(Effect):
        kind = "tip_spring"
        parameters = ("k",); units = ("N/m",); lower = (0.0,); upper = (np.inf,); scale = (1e5,)
        def __init__(self, model): self.model = model
        def locations(self): return ["tip"]
        def terms(self, alpha, location, values): ...   # a Terms, linear in values

    register_effect("tip_spring", TipSpring)
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..assembly import DOFS_PER_NODE, SegmentedMatrix, cell_dofs
from ..solvers.frf import direct_frf, hz_to_rad, krylov_frf
from ..elements.hex8 import element_stiffness
from ..model import ParametricModel, check_parameters

__all__ = [
    "Terms",
    "Effect",
    "Applied",
    "SegmentMass",
    "PointMass",
    "GroundedSpring",
    "ElementBand",
    "RayleighDamping",
    "register_effect",
    "unregister_effect",
    "registered_effects",
    "build_library",
    "extended_matrices",
    "extended_frf",
    "LinearisedResponse",
    "joint_bands",
    "candidate_nodes",
    "SensorMass",
    "SensorGain",
    "patch_bands",
    "sensor_gain",
    "MASS_SHARE",
    "node_rows",
    "has_cell_stiffness",
    "patch_centres",
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
    return rows[model._node_rows_cache[2][int(node)]]


def candidate_nodes(model: ParametricModel, node_set: str = "top", component: int | None = None) -> np.ndarray:
    """Nodes of a named set whose DOFs are all free (all such nodes if the set or the mesh is absent);
    with ``component``, the nodes whose DOF along that axis is free."""
    nodes, rows = node_rows(model)
    if model.mesh is not None and node_set in model.mesh.node_sets:
        pick = np.asarray(model.mesh.node_sets[node_set])
        nodes, rows = nodes[pick], rows[pick]
    if component is not None:
        return nodes[rows[:, component] >= 0]
    # Every DOF the node has is free (a matrices model may lack some translations: -2).
    return nodes[np.all(rows != -1, axis=1) & np.any(rows >= 0, axis=1)]


def _diag(n: int, rows: np.ndarray, values: np.ndarray) -> sp.csr_matrix:
    return sp.csr_matrix((values, (rows, rows)), shape=(n, n))


def _segment_cells(model: ParametricModel) -> list[np.ndarray]:
    if model.cell_segment is not None:
        return [np.flatnonzero(model.cell_segment == i) for i in range(len(model.segment_names))]
    try:
        return [model.mesh.cell_sets[name] for name in model.segment_names]
    except KeyError as exc:
        raise ValueError(f"segment {exc.args[0]!r} is not a cell set of the mesh; element bands need "
                         f"the segments' cells") from exc


# -- built-in effects ---------------------------------------------------------------------------------
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
        if self.model.mesh is None:  # a matrices model: no coordinates
            return {"node": n}
        x, y, z = self.model.mesh.nodes[n]
        return {"node": n, "x_m": float(x), "y_m": float(y), "z_m": float(z)}

    def position(self, location) -> np.ndarray | None:
        return None if self.model.mesh is None else self.model.mesh.nodes[self.node(location)].copy()

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


#: Default plausible share of the structure's mass for an added mass.
MASS_SHARE = 0.2


class PointMass(_NodalEffect):
    """A point mass at a node (translational, on u_x, u_y and u_z); at most :data:`MASS_SHARE` of the model."""

    kind = "point_mass"
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


class GroundedSpring(_NodalEffect):
    """A translational spring from a node to ground, along one axis (u_z by default)."""

    kind = "grounded_spring"
    parameters = ("k",)
    units = ("N/m",)
    lower = (0.0,)
    upper = (1e8,)
    scale = (1e5,)
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


def has_cell_stiffness(model: ParametricModel) -> bool:
    """True if the model can give its cells' element stiffness (a mesh with known elements and materials)."""
    return model.mesh is not None and (model.cell_stiffness is not None
                                       or (model.material is not None and model.formulation is not None))


def _cells_stiffness(model: ParametricModel, cells: np.ndarray) -> np.ndarray:
    """Element stiffness matrices of ``cells`` at alpha = 0, shape (c, d, d), N/m.

    From the model's own ``cell_stiffness`` (a model file: any element family and
    material per cell), else hex8 with the model's material; the benchmark's 544
    cells are computed once and cached on the model.
    """
    if not has_cell_stiffness(model):
        where = f" ({model.source})" if model.source else ""
        raise ValueError(f"effects on a set of cells need the element matrices of a mesh; this model{where} "
                         + ("has no mesh (it is given as matrices)" if model.mesh is None else
                            "does not give them (several materials without cell_stiffness)"))
    if model.cell_stiffness is not None:
        return model.cell_stiffness(cells)
    Ke = getattr(model, "_cell_stiffness_cache", None)
    if Ke is None:
        Ke = model._cell_stiffness_cache = element_stiffness(model.mesh.cell_coords, model.material.D,
                                                             model.formulation)
    return Ke[cells]


def _band_matrix(model: ParametricModel, cells: np.ndarray, owner: np.ndarray) -> SegmentedMatrix:
    """The stiffness of ``cells`` on the free DOFs, split by the segment owning each cell (cells
    in no segment are the fixed part, not scaled by alpha).

    Assembled directly on the free DOFs from the cached element matrices (entries on a
    constrained DOF dropped): a few milliseconds per band, so hundreds of patches cost
    well under a second.
    """
    Ke = _cells_stiffness(model, cells)  # (c, d, d)
    dofs = _free_position(model)[cell_dofs(model.mesh.cells[cells])]  # (c, d), -1 = constrained
    d = dofs.shape[1]
    rows = np.repeat(dofs, d, axis=1).ravel()
    cols = np.tile(dofs, (1, d)).ravel()
    m = model.n_segments
    seg = np.repeat(np.where(owner[cells] >= 0, owner[cells], m), d * d)  # row m: cells in no segment
    keep = (rows >= 0) & (cols >= 0)
    rows, cols, seg, vals = rows[keep], cols[keep], seg[keep], Ke.ravel()[keep]
    n = model.n_dofs
    keys, slot = np.unique(rows.astype(np.int64) * n + cols, return_inverse=True)
    data = np.bincount(seg * keys.size + slot, weights=vals, minlength=(m + 1) * keys.size).reshape(m + 1, -1)
    counts = np.bincount(keys // n, minlength=n)
    pattern = sp.csr_matrix((data.sum(axis=0), (keys % n).astype(np.int32),
                             np.concatenate([[0], np.cumsum(counts)])), shape=(n, n))
    fixed = data[m] if np.any(owner[cells] < 0) else None
    return SegmentedMatrix(pattern=pattern, data=data[:m], fixed=fixed)


class ElementBand(Effect):
    """Stiffness factor of a band of elements: their K_e (1 + alpha_s) -> K_e (1 + alpha_s)(1 + beta).

    ``beta > -1`` keeps K positive definite. ``bands`` maps a location label
    to the cells of that band; the plate joints of the benchmark are one use
    (:func:`joint_bands`), any set of cells is another.
    """

    kind = "element_band"
    parameters = ("beta",)
    units = ("-",)
    lower = (-1.0,)
    #: A band more than twice as stiff as the plate it is part of needs material the model lacks (a
    #: stiffener), not damage or a joint's flexibility: implausible by default (``set_limits`` widens it).
    upper = (1.0,)
    scale = (0.1,)
    margin = (1e-3,)

    def __init__(self, model: ParametricModel, bands: dict[str, np.ndarray], kind: str | None = None):
        super().__init__(model)
        if kind:
            self.kind = kind
        _cells_stiffness(model, np.zeros(0, dtype=int))  # refuses a model without element matrices
        self.bands = {label: np.asarray(cells, dtype=int) for label, cells in bands.items()}
        seg_cells = _segment_cells(model)
        owner = np.full(model.mesh.n_cells, -1)
        for s, cells in enumerate(seg_cells):
            owner[cells] = s
        self._matrices: dict[str, SegmentedMatrix] = {}
        for label, cells in self.bands.items():
            if cells.size == 0:
                raise ValueError(f"element band {label!r} has no cells")
            self._matrices[label] = _band_matrix(model, cells, owner)

    def locations(self) -> list[str]:
        return list(self.bands)

    def band_stiffness(self, alpha, location) -> sp.csr_matrix:
        """The band's share of ``K(alpha)``, N/m."""
        alpha = check_parameters(alpha, self.model.n_segments, "alpha")
        return self._matrices[location].combine(1.0 + alpha)

    def terms(self, alpha, location, values) -> Terms:
        return Terms(stiffness=float(values[0]) * self.band_stiffness(alpha, location))

    def alpha_derivative(self, alpha, location, values, index) -> Terms:
        return Terms(stiffness=float(values[0]) * self._matrices[location].segment(index))

    def position(self, location) -> np.ndarray:
        return self.model.mesh.centroids[self.bands[location]].mean(axis=0)

    def describe(self, location) -> dict:
        cells = self.bands[location]
        c = self.model.mesh.centroids[cells]
        return {"cells": int(cells.size), "x_min_m": float(c[:, 0].min()), "x_max_m": float(c[:, 0].max())}


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


def _sensor_nodes(model: ParametricModel) -> np.ndarray:
    """Node of each sensor, shape (n_sensors,)."""
    nodes = getattr(model, "sensor_nodes", None)
    if nodes is not None:
        return np.asarray(nodes, dtype=int)
    # The node of the DOFs each output vector reads (a sensor along a vector reads one node's DOFs).
    L = model.outputs.tocsc()
    first = L.indices[L.indptr[:-1]]  # a free-DOF index per sensor
    all_nodes, rows = node_rows(model)
    owner = np.full(model.n_dofs, -1)
    for c in range(DOFS_PER_NODE):
        ok = rows[:, c] >= 0
        owner[rows[ok, c]] = all_nodes[ok]
    return owner[first]


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


class SensorGain(Effect):
    """A calibration error of one sensor: the measured amplitude is ``|Z_s| (1 + g)``.

    Changes the comparison, not the structure (no matrix changes): the
    predicted amplitude at that sensor is scaled. Plausible within +-50 %.
    """

    kind = "sensor_gain"
    parameters = ("g",)
    units = ("-",)
    lower = (-0.5,)
    upper = (0.5,)
    scale = (0.05,)

    def locations(self) -> list[str]:
        return [f"sensor {s + 1}" for s in range(self.model.n_sensors)]

    def terms(self, alpha, location, values) -> Terms:
        gain = np.zeros(self.model.n_sensors)
        gain[self.locations().index(location)] = float(values[0])
        return Terms(gain=gain)

    def describe(self, location) -> dict:
        s = self.locations().index(location)
        return {"sensor": s + 1, "node": int(_sensor_nodes(self.model)[s])}


def patch_bands(model: ParametricModel, centres: Sequence[int], rings: Sequence[int] = (1, 2)) -> dict[str, np.ndarray]:
    """Cells within ``r`` rings of each centre node (ring 1: the cells touching it), labelled
    ``node <n> r<r>``: patches for damage localisation anywhere."""
    cells = model.mesh.cells
    bands = {}
    for n in centres:
        nodes = np.array([n])
        for r in range(1, max(rings) + 1):
            inside = np.flatnonzero(np.any(np.isin(cells, nodes), axis=1))
            if r in rings:
                bands[f"node {int(n)} r{r}"] = inside
            nodes = np.unique(cells[inside])
    return bands


def patch_centres(model: ParametricModel, n_target: int = 160) -> np.ndarray:
    """About ``n_target`` patch centres spread over any mesh: the node nearest the mean of the free
    nodes in each box of a grid, refined until that many boxes hold nodes."""
    nodes = candidate_nodes(model, node_set="")
    xyz = model.mesh.nodes[nodes]
    lo = xyz.min(axis=0)
    h = float(np.ptp(xyz, axis=0).max())
    while True:
        boxes, which = np.unique(np.floor((xyz - lo) / h).astype(np.int64), axis=0, return_inverse=True)
        if boxes.shape[0] >= min(n_target, nodes.size) or h <= 0:
            break
        h /= 1.25
    which = which.ravel()
    mean = np.zeros((boxes.shape[0], 3))
    np.add.at(mean, which, xyz)
    mean /= np.bincount(which)[:, None]
    dist = np.linalg.norm(xyz - mean[which], axis=1)
    order = np.lexsort((dist, which))  # per box, nearest first
    first = order[np.r_[True, np.diff(which[order]) != 0]]
    return np.sort(nodes[first])


def _patch_factory(model: ParametricModel, stride: int = 2) -> Effect | None:
    """Patches of 1 and 2 rings of cells around centre nodes: on a model with a ``top`` node set (the
    benchmark) every ``stride``-th top node in x and y (a 2 x 2 subgrid of the top surface: neighbouring
    patches overlap, so no damage falls between them); on any other mesh :func:`patch_centres`.
    None for a model without element matrices (matrices only)."""
    if not has_cell_stiffness(model):
        return None
    if "top" in model.mesh.node_sets:
        top = candidate_nodes(model, "top")
        xy = np.round(model.mesh.nodes[top, :2], 9)
        xs, ys = np.unique(xy[:, 0]), np.unique(xy[:, 1])
        keep = np.isin(xy[:, 0], xs[::stride]) & np.isin(xy[:, 1], ys[::stride])
        centres = top[keep]
    else:
        centres = patch_centres(model)
    return ElementBand(model, patch_bands(model, centres), kind="patch")


def _cell_set_factory(model: ParametricModel) -> Effect | None:
    """The stiffness factor of every named cell set of the mesh (``set <name>``), except sets made of
    whole segments (their factor is a combination of the alphas); None if there is none."""
    if not has_cell_stiffness(model):
        return None
    segments = _segment_cells(model)
    owner = np.full(model.mesh.n_cells, -1)
    for s, cells in enumerate(segments):
        owner[cells] = s
    bands = {}
    for name, cells in model.mesh.cell_sets.items():
        cells = np.asarray(cells, dtype=int)
        touched = np.unique(owner[cells])
        whole = touched.min() >= 0 and sum(segments[t].size for t in touched) == np.unique(cells).size
        if cells.size and not whole:
            bands[f"set {name}"] = cells
    return ElementBand(model, bands, kind="cell_set") if bands else None


def joint_bands(model: ParametricModel, joints_x: Sequence[float], atol: float = 1e-9) -> dict[str, np.ndarray]:
    """Cells touching each joint plane ``x = x_j``: one band per joint, labelled ``joint x=<mm> mm``."""
    nodes_x = model.mesh.nodes[:, 0]
    bands = {}
    for xj in joints_x:
        on_plane = np.abs(nodes_x - xj) <= atol
        cells = np.flatnonzero(np.any(on_plane[model.mesh.cells], axis=1))
        if cells.size == 0:
            raise ValueError(f"no cells touch the plane x = {xj} m")
        bands[f"joint x={1e3 * xj:g} mm"] = cells
    return bands


def _block_joints(model: ParametricModel) -> list[float]:
    """x of the planes where consecutive ``plate<k>`` cell sets meet (the benchmark's joints)."""
    names = sorted((n for n in model.mesh.cell_sets if n.startswith("plate") and n[5:].isdigit()),
                   key=lambda n: int(n[5:]))
    joints = []
    for left, right in zip(names, names[1:]):
        a = np.unique(model.mesh.cells[model.mesh.cell_sets[left]])
        b = np.unique(model.mesh.cells[model.mesh.cell_sets[right]])
        shared = np.intersect1d(a, b)
        xs = np.unique(np.round(model.mesh.nodes[shared, 0], 9))
        if xs.size == 1:
            joints.append(float(xs[0]))
    return joints


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
}


def _joint_factory(model: ParametricModel) -> Effect | None:
    if not has_cell_stiffness(model):
        return None
    joints = _block_joints(model)
    if not joints:
        return None
    return ElementBand(model, joint_bands(model, joints), kind="joint_band")


register_effect("segment_mass", SegmentMass)
register_effect("point_mass", PointMass)
register_effect("grounded_spring", GroundedSpring)
register_effect("joint_band", _joint_factory)
register_effect("damping", RayleighDamping)
register_effect("grounded_spring_x", lambda model: GroundedSpring(model, component=0))
register_effect("grounded_spring_y", lambda model: GroundedSpring(model, component=1))
register_effect("sensor_mass", SensorMass)
register_effect("sensor_gain", SensorGain)
register_effect("patch", _patch_factory)
register_effect("cell_set", _cell_set_factory)


# -- the extended model -------------------------------------------------------------------------------
def extended_matrices(model: ParametricModel, alpha, applied: Sequence[Applied] = ()):
    """``K, M, a, b`` of the model at ``alpha`` with the applied effects added."""
    alpha = check_parameters(alpha, model.n_segments, "alpha")
    K = model.stiffness(alpha)
    M = getattr(model, "_effects_mass", None)
    if M is None:  # M(gamma = 0) never changes: assemble it once per model
        M = model._effects_mass = model.mass()
    a, b = model.damping
    for item in applied:
        t = item.terms(alpha)
        if t.gain is not None:
            continue
        if t.stiffness is not None:
            K = K + t.stiffness
        if t.mass is not None:
            M = M + t.mass
        a += t.damping_a
        b += t.damping_b
    return sp.csr_matrix(K), sp.csr_matrix(M), a, b


def extended_frf(model: ParametricModel, alpha, freqs_hz, applied: Sequence[Applied] = (),
                 method: str = "krylov") -> np.ndarray:
    """Receptance at the sensors (the model's output vectors) under its load, with effects; shape (p, n_sensors),
    m/N (the benchmark's load is the combined one)."""
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    if freqs.ndim != 1 or freqs.size == 0 or np.any(~(freqs > 0)):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive values in Hz, got {freqs_hz!r}")
    K, M, a, b = extended_matrices(model, alpha, applied)
    F = model.combined_load()
    omegas = hz_to_rad(freqs)
    rows = model._out_rows  # the DOFs the output vectors read
    if method == "direct":
        Z = direct_frf(K, M, a * M + b * K, F, omegas, rows)[:, :, 0]
    elif method == "krylov":
        Z = krylov_frf(K, M, a, b, F, omegas, rows)[:, :, 0]
    else:
        raise ValueError(f"unknown FRF method {method!r}; choose 'krylov' or 'direct'")
    return (Z @ model._out_weights) * (1.0 + sensor_gain(model, alpha, applied))[None, :]


def segment_stiffness(model: ParametricModel, i: int) -> sp.csr_matrix:
    """Segment ``i``'s stiffness at alpha = 0 without the common pattern's explicit zeros (cached on the
    model): a derivative with respect to alpha_i touches only the segment's rows."""
    cache = model.__dict__.setdefault("_segment_stiffness_cache", {})
    if i not in cache:
        K = model.stiffness_segments.segment(i).copy()  # the segment shares the pattern's index arrays
        K.eliminate_zeros()
        cache[i] = K
    return cache[i]


def sensor_gain(model: ParametricModel, alpha, applied: Sequence[Applied] = ()) -> np.ndarray:
    """Sum of the applied sensor gains, shape (n_sensors,) (zero without any)."""
    g = np.zeros(model.n_sensors)
    for item in applied:
        t = item.terms(alpha)
        if t.gain is not None:
            g = g + t.gain
    return g


class LinearisedResponse:
    """First-order change of ln|Z| at the sensors for any change of (K, M, a, b).

    With ``D(w) = K - w^2 M + j w (a M + b K)``, the model's load F and output
    vectors ``l_s``, the field is ``h = D^-1 F``, ``Z_s = l_s^T h`` and
    ``dZ_s = -l_s^T D^-1 dD h``. D is complex symmetric, so ``l_s^T D^-1`` is
    the response ``X_s`` to a unit load along ``l_s`` (reciprocity), and
    ``dZ_s = -X_s^T (dD h)``: one Krylov space of F and the sensor loads
    (:class:`fe_core.solvers.adjoint.ReducedResponse`) gives the sensitivity to *every*
    candidate, e.g. a point mass at each of hundreds of nodes, without a solve
    per candidate.

    Parameters
    ----------
    model : ParametricModel
    alpha : array_like
    freqs_hz : array_like, shape (p,)
    applied : sequence of Applied
        Effects already in the model (the point of linearisation).
    """

    def __init__(self, model: ParametricModel, alpha, freqs_hz, applied: Sequence[Applied] = ()):
        from ..solvers.adjoint import ReducedResponse

        self.model = model
        self.alpha = check_parameters(alpha, model.n_segments, "alpha")
        self.freqs_hz = np.asarray(freqs_hz, float)
        self.omegas = hz_to_rad(self.freqs_hz)
        self.applied = list(applied)
        self.K, self.M, self.a, self.b = extended_matrices(model, alpha, applied)
        self.gain = sensor_gain(model, self.alpha, self.applied)
        self.reduced = ReducedResponse(self.K, self.M, self.a, self.b, model.combined_load(), model.outputs,
                                       self.omegas, self.gain)
        self.Z = self.reduced.Z  # (p, n_s), without the gains

    @property
    def amplitude(self) -> np.ndarray:
        """The compared amplitude ``|Z| (1 + gain)``, shape (p, n_sensors), m/N."""
        return self.reduced.amplitude

    def derivative(self, terms: Terms) -> np.ndarray:
        """``d ln|Z_s(f)|`` per unit of the change described by ``terms``, shape (p, n_sensors)."""
        return self.reduced.dlog(terms.stiffness, terms.mass, terms.damping_a, terms.damping_b, terms.gain)

    def alpha_derivatives(self) -> np.ndarray:
        """``d ln|Z| / d alpha_i``, shape (p * n_sensors, n_segments), frequency-major rows.

        Includes the alpha-dependence of the applied effects (an element band
        scales with its segments' factors).
        """
        cols = []
        for i in range(self.model.n_segments):
            dK = segment_stiffness(self.model, i)
            for item in self.applied:
                extra = item.effect.alpha_derivative(self.alpha, item.location, item.values, i)
                if extra is not None and extra.stiffness is not None:
                    dK = dK + extra.stiffness
            cols.append(self.derivative(Terms(stiffness=dK)).ravel())
        return np.column_stack(cols)

    def batch_derivatives(self, effect: Effect, locations: Sequence[str]) -> np.ndarray:
        """``d ln|Z| / d values`` of an effect at many locations, shape (L, p * n_sensors, k): in one
        product for a diagonal effect (:meth:`Effect.diagonal`), else location by location."""
        diag = effect.diagonal(locations) if effect.n_parameters == 1 else None
        if diag is not None:
            d = self.reduced.diagonal_dlog(*diag)
            return d.reshape(len(locations), -1, 1)
        return np.stack([self.effect_derivatives(effect, loc) for loc in locations]) if locations else \
            np.zeros((0, self.Z.size, effect.n_parameters))

    def effect_derivatives(self, effect: Effect, location: str) -> np.ndarray:
        """``d ln|Z| / d values`` of an effect at a location, shape (p * n_sensors, k)."""
        return np.column_stack([self.derivative(effect.derivative(self.alpha, location, i)).ravel()
                                for i in range(effect.n_parameters)])
