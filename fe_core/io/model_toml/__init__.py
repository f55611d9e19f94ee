"""The model file ``model.toml``: schema, checks and assembly of a :class:`ParametricModel`.

A model is a mesh (read through meshio) or exported matrices, with segments,
supports, damping, sensors and excitations. Paths are relative to the model
file. Every refusal is a :class:`ModelFileError` naming the file and the key::

    units = "SI"                       # or "mm-t-s" (mm, tonne, s: E in MPa, rho in t/mm^3)
    mesh = "three_plate.inp"           # .msh (Gmsh 4), .inp (Abaqus), .vtu, ...: or a [matrices] table
    point_tolerance = 1e-3             # nearest-node distance allowed for points (mesh units)
    point_placement = "nearest"        # or "interpolate": a mesh model reads points through the element
                                       # holding them (shape functions; point_tolerance: how far outside)
    excitation = "combined"            # which excitation drives the FRF (default: the only one)

    [damping]                          # Rayleigh C = a M + b K
    a = 1e-2                           # 1/s
    b = 1e-4                           # s

    [elements.hexahedron]              # options of an element family (optional)
    formulation = "incompatible"

    [[materials]]                      # per cell set ("cells" omitted: every cell)
    cells = ["plate1", "plate2"]
    E = 2.06e11                        # Pa
    nu = 0.3
    rho = 7850.0                       # kg/m^3

    [[segments]]                       # stiffness factor alpha_i of a cell set, in this order
    set = "segment1"
    bounds = [-1.0, 1.0]               # optional (default: the run's lower/upper)
    update = ["stiffness", "mass"]     # optional: also its mass factor gamma_i (default ["stiffness"])
    mass_bounds = [-0.5, 0.5]          # optional, with "mass": gamma_i's box

    [[supports]]                       # a node set (or a cell set's nodes) and the fixed directions
    nodes = "clamped"                  # or a list of node indices
    fix = ["x", "y", "z"]

    [[sensors]]                        # response DOFs, in the measured data's order (sensor 1, 2, ...)
    name = "s1"
    point = [0.0359, 0.02, 0.01]       # or node = 17
    direction = "z"                    # x, y, z or a vector [nx, ny, nz]
    test_node = 1                      # optional: the test's node id (UFF58 response/reference node)
    test_direction = "+z"              # optional: the test's direction code (default: direction if x, y, z)

    [[excitations]]
    name = "combined"
    dofs = [{ point = [0.0359, 0.02, 0.01], direction = "z", weight = 1.0 }, ...]
                                       # or point / node, direction, weight directly
                                       # test_node / test_direction as for sensors (both needed with dofs)

A matrices model replaces ``mesh`` by::

    [matrices]
    dofs = "dofs.csv"                  # header node,direction; one row per matrix row
    stiffness = "K0.mtx"               # optional fixed remainder K_0, M_0
    mass = "M0.mtx"

    [[segments]]
    name = "web"
    stiffness = "K_web.mtx"            # .mtx or .npz (scipy.sparse.save_npz)
    mass = "M_web.mtx"

with supports as lists of node ids from the DOF table and sensors/excitations
given by ``node`` (points need coordinates, which matrices do not carry).

A CalculiX deck replaces ``mesh`` by ``solver = "calculix"`` and ``deck = "panel.inp"``
(:mod:`.calculix_model`; docs/guide/solver-decks.md).

The package: :mod:`.spec` (loading, checks, shared tables), :mod:`.sensors` (sensors, excitations, test
DOFs), :mod:`.mesh_model` and :mod:`.matrices_model` (the two builders); :func:`read_model_toml` here
chooses between them.
"""

from __future__ import annotations

from pathlib import Path

from ...model import ParametricModel
from .matrices_model import _matrices_model
from .mesh_model import _mesh_model
from .spec import UNITS, ModelFileError, _get, _keys, _load, model_files

__all__ = ["ModelFileError", "read_model_toml", "model_files", "UNITS"]


def read_model_toml(path: str | Path) -> ParametricModel:
    """Read, check and assemble the model of a ``model.toml`` file.

    Raises
    ------
    ModelFileError
        Naming the file and key, for every problem found before or during assembly.
    """
    path = Path(path)
    spec = _load(path)
    units = _get(spec, spec.data, "units", "", (str,), "SI")
    if units not in UNITS:
        raise spec.error("units", f"unknown unit system {units!r}; choose one of {', '.join(UNITS)}")
    damping = spec.data.get("damping", {})
    if not isinstance(damping, dict):
        raise spec.error("damping", f"must be a table with a and b, got {type(damping).__name__}")
    _keys(spec, damping, {"a", "b"}, "damping")
    a = _get(spec, damping, "a", "damping", (float,), 0.0)
    b = _get(spec, damping, "b", "damping", (float,), 0.0)
    if a < 0 or b < 0:
        raise spec.error("damping", f"Rayleigh coefficients must be >= 0, got a = {a}, b = {b}")
    if "mesh" in spec.data:
        return _mesh_model(spec, units, (a, b))
    if "deck" in spec.data and "parameters" in spec.data:
        from .calculix_blackbox import _blackbox_model   # route B: factors on numbers of the deck

        return _blackbox_model(spec, units, (a, b))
    if "deck" in spec.data:
        from .calculix_model import _calculix_model

        return _calculix_model(spec, units, (a, b))
    return _matrices_model(spec, units, (a, b))
