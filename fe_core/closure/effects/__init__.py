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
(:func:`fe_core.closure.decisions.at_bound`).

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

The package holds one module per family of effects, and the registry of the built-in ones here:

* :mod:`.base`: :class:`Terms`, :class:`Effect`, :class:`Applied`, node helpers and the registry;
* :mod:`.masses`: ``segment_mass``, ``point_mass``, ``sensor_mass``;
* :mod:`.springs`: ``grounded_spring`` (and its ``_x``, ``_y`` variants);
* :mod:`.bands`: ``joint_band``, ``patch``, ``cell_set`` (:class:`ElementBand` on sets of cells);
* :mod:`.damping`: ``damping``;
* :mod:`.sensors`: ``sensor_gain``;
* :mod:`.extended`: the extended model's matrices and FRF, and :class:`LinearisedResponse`.

Every name is importable from the package (``from fe_core.closure.effects import PointMass``); the
built-in effects are registered below, in the order :func:`registered_effects` lists them (it decides
ties and the order of outputs).
"""

from __future__ import annotations

from ...assembly import DOFS_PER_NODE  # re-exported: benchmarks/make/closure_table.py uses it
from .bands import (
    ElementBand,
    PatchBands,
    _cell_set_factory,
    _joint_factory,
    _patch_factory,
    has_cell_stiffness,
    joint_bands,
    patch_bands,
    patch_centres,
)
from .base import (
    Applied,
    Effect,
    EffectFactory,
    Terms,
    _free_position,  # used by benchmarks/make/closure_table.py
    build_library,
    candidate_nodes,
    node_rows,
    register_effect,
    registered_effects,
    unregister_effect,
)
from .damping import RayleighDamping
from .extended import LinearisedResponse, extended_frf, extended_matrices, segment_stiffness, sensor_gain
from .masses import MASS_SHARE, PointMass, SegmentMass, SensorMass, _sensor_mass_factory
from .sensors import SensorGain
from .springs import GroundedSpring

__all__ = [
    "Terms",
    "Effect",
    "Applied",
    "SegmentMass",
    "PointMass",
    "GroundedSpring",
    "ElementBand",
    "PatchBands",
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


register_effect("segment_mass", SegmentMass)
register_effect("point_mass", PointMass)
register_effect("grounded_spring", GroundedSpring)
register_effect("joint_band", _joint_factory)
register_effect("damping", RayleighDamping)
register_effect("grounded_spring_x", lambda model: GroundedSpring(model, component=0))
register_effect("grounded_spring_y", lambda model: GroundedSpring(model, component=1))
register_effect("sensor_mass", _sensor_mass_factory)
register_effect("sensor_gain", SensorGain)
register_effect("patch", _patch_factory)
register_effect("cell_set", _cell_set_factory)
