"""The model file ``model.toml``: schema, checks and assembly of a :class:`ParametricModel`.

A model is a mesh (read through meshio) or exported matrices, with segments,
supports, damping, sensors and excitations. Paths are relative to the model
file. Every refusal is a :class:`ModelFileError` naming the file and the key::

    units = "SI"                       # or "mm-t-s" (mm, tonne, s: E in MPa, rho in t/mm^3)
    mesh = "three_plate.inp"           # .msh (Gmsh 4), .inp (Abaqus), .vtu, ...: or a [matrices] table
    point_tolerance = 1e-3             # nearest-node distance allowed for points (mesh units)
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
"""

from __future__ import annotations

import logging
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..assembly import DOFS_PER_NODE, SegmentedMatrix, assemble, cell_dofs, free_dof_map
from ..material import Material
from ..model import ParametricModel
from .matrices import DIRECTIONS, MatrixFileError, check_symmetric_psd, read_dof_table, read_matrix
from .mesh_file import MeshFile, MeshFileError, read_mesh

__all__ = ["ModelFileError", "read_model_toml", "model_files", "UNITS"]

log = logging.getLogger(__name__)

#: Unit systems: (length to m, stress to Pa, density to kg/m^3).
UNITS = {"SI": (1.0, 1.0, 1.0), "mm-t-s": (1e-3, 1e6, 1e12)}

_TOP_KEYS = {"units", "mesh", "matrices", "point_tolerance", "excitation", "damping", "elements", "materials",
             "segments", "supports", "sensors", "excitations", "name", "description"}


class ModelFileError(ValueError):
    """A model file that cannot be used; the message names the file and the key."""


@dataclass
class _Spec:
    """The model file's tables after type checks (paths resolved)."""

    path: Path
    data: dict

    def error(self, key: str, why: str) -> ModelFileError:
        return ModelFileError(f"{self.path}: key '{key}': {why}")

    def file(self, key: str, value: str) -> Path:
        p = Path(value)
        p = p if p.is_absolute() else self.path.parent / p
        if not p.exists():
            raise self.error(key, f"file {str(p)!r} does not exist")
        return p


_MISSING = object()


def _get(spec: _Spec, table: dict, key: str, where: str, types: tuple, default: Any = _MISSING) -> Any:
    name = f"{where}.{key}" if where else key
    if key not in table:
        if default is _MISSING:
            raise spec.error(name, "is missing")
        return default
    value = table[key]
    numeric = float in types
    ok = isinstance(value, types) or (numeric and isinstance(value, int))
    if isinstance(value, bool) and bool not in types:
        ok = False
    if not ok:
        names = " or ".join("number" if t is float else "table" if t is dict else t.__name__ for t in types)
        raise spec.error(name, f"must be {names}, got {type(value).__name__} {value!r}")
    return float(value) if numeric and isinstance(value, int) and not isinstance(value, bool) else value


def _keys(spec: _Spec, table: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise spec.error(f"{where}.{unknown[0]}" if where else unknown[0],
                         f"unknown key; valid keys here are {', '.join(sorted(allowed))}")


def _tables(spec: _Spec, key: str, required: bool = True) -> list[dict]:
    value = spec.data.get(key)
    if value is None:
        if required:
            raise spec.error(key, f"is missing: give at least one [[{key}]] table")
        return []
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise spec.error(key, f"must be an array of tables ([[{key}]]), got {type(value).__name__}")
    if required and not value:
        raise spec.error(key, f"is empty: give at least one [[{key}]] table")
    return value


def _load(path: Path) -> _Spec:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such model file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: cannot read the model file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelFileError(f"{path}: not valid TOML ({exc})") from None
    spec = _Spec(path, data)
    _keys(spec, data, _TOP_KEYS, "")
    if ("mesh" in data) == ("matrices" in data):
        raise spec.error("mesh", "give exactly one of 'mesh' (a mesh file) or a [matrices] table")
    return spec


def model_files(path: str | Path) -> list[Path]:
    """The model file and every file it refers to (mesh, matrices, DOF table), existing ones only."""
    path = Path(path)
    spec = _load(path)
    out = [path]
    names = []
    if isinstance(spec.data.get("mesh"), str):
        names.append(spec.data["mesh"])
    mat = spec.data.get("matrices")
    if isinstance(mat, dict):
        names += [v for v in mat.values() if isinstance(v, str)]
    for seg in spec.data.get("segments", []) if isinstance(spec.data.get("segments"), list) else []:
        if isinstance(seg, dict):
            names += [seg[k] for k in ("stiffness", "mass") if isinstance(seg.get(k), str)]
    for name in names:
        p = Path(name) if Path(name).is_absolute() else path.parent / name
        if p.exists():
            out.append(p)
    return out


# -- directions, points and nodes --------------------------------------------------------------
def _direction(spec: _Spec, value: Any, key: str) -> np.ndarray:
    """A unit vector from ``"x"``, ``"y"``, ``"z"`` or ``[nx, ny, nz]`` (normalised)."""
    if isinstance(value, str):
        if value.lower() not in ("x", "y", "z"):
            raise spec.error(key, f"unknown direction {value!r}; use x, y, z or a vector [nx, ny, nz]")
        return np.eye(3)[DIRECTIONS[value.lower()]]
    if (isinstance(value, list) and len(value) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        v = np.asarray(value, float)
        if np.linalg.norm(v) > 0 and np.all(np.isfinite(v)):
            return v / np.linalg.norm(v)
    raise spec.error(key, f"must be x, y, z or a non-zero vector [nx, ny, nz], got {value!r}")


@dataclass
class _Locator:
    """Finds nodes for sensors and excitations and records where they landed."""

    spec: _Spec
    mesh_file: MeshFile | None
    nodes: np.ndarray | None       # coordinates in file units (mesh models)
    node_ids: np.ndarray | None    # DOF-table node ids (matrices models)
    tolerance: float

    def node(self, table: dict, where: str) -> tuple[int, str]:
        """(node index, a sentence saying where it is) of a ``node`` or ``point`` entry."""
        spec = self.spec
        if ("node" in table) == ("point" in table):
            raise spec.error(f"{where}.node", "give exactly one of 'node' (an index) or 'point' ([x, y, z])")
        if "node" in table:
            value = _get(spec, table, "node", where, (int,))
            if self.mesh_file is not None:
                try:
                    return self.mesh_file.node_from_file(value), f"node {value}"
                except ValueError as exc:
                    raise spec.error(f"{where}.node", str(exc)) from None
            hit = np.flatnonzero(self.node_ids == value)
            if hit.size == 0:
                raise spec.error(f"{where}.node", f"node {value} is not in the DOF table")
            return int(value), f"node {value}"
        point = table["point"]
        if not (isinstance(point, list) and len(point) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in point)):
            raise spec.error(f"{where}.point", f"must be [x, y, z], got {point!r}")
        if self.nodes is None:
            raise spec.error(f"{where}.point", "a matrices model has no node coordinates: give 'node'")
        dist = np.linalg.norm(self.nodes - np.asarray(point, float), axis=1)
        i = int(np.argmin(dist))
        if dist[i] > self.tolerance:
            raise spec.error(f"{where}.point", f"the nearest node to {point} is {dist[i]:.6g} (mesh units) away at "
                                               f"{self.nodes[i].tolist()}, beyond point_tolerance = {self.tolerance:.6g}")
        return i, f"nearest node {i} at {dist[i]:.3g} from {point}"


# -- the model ---------------------------------------------------------------------------------
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
    return _matrices_model(spec, units, (a, b))


def _bounds(spec: _Spec, value: Any, key: str, segment: str, symbol: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise spec.error(key, f"must be [lower, upper], got {value!r}")
    lo, hi = map(float, value)
    what = "stiffness" if symbol == "alpha" else "mass"
    if not (-1.0 <= lo < hi and np.isfinite(hi)):
        raise spec.error(key, f"segment {segment!r}: need -1 <= lower < upper ({symbol} > -1 keeps the {what} "
                              f"positive), got {value!r}")
    return lo, hi


#: What a segment's ``update`` may list: its stiffness factor alpha (always) and its mass factor gamma.
UPDATES = ("stiffness", "mass")


def _segment_parameters(spec: _Spec, tables: list[dict], names: list[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """The segments whose mass factor is updated (``update = ["stiffness", "mass"]``), and the parameter
    bounds, shape (n_parameters, 2) in the model's parameter order (alphas, then the gammas), +-inf where
    none is given, or None when no segment gives any."""
    mass, alpha_bounds, gamma_bounds = [], [], []
    for i, seg in enumerate(tables):
        where = f"segments[{i}]"
        update = seg.get("update", ["stiffness"])
        if not (isinstance(update, list) and all(isinstance(u, str) for u in update)) \
                or set(update) - set(UPDATES) or len(set(update)) != len(update):
            raise spec.error(f"{where}.update", f"must be a list of distinct {' and '.join(UPDATES)}, got {update!r}")
        if "stiffness" not in update:
            raise spec.error(f"{where}.update", f"segment {names[i]!r}: a segment's stiffness factor alpha is "
                                                "always updated; list \"stiffness\" (a cell set whose stiffness is "
                                                "fixed belongs to no segment)")
        alpha_bounds.append(_bounds(spec, seg["bounds"], f"{where}.bounds", names[i], "alpha") if "bounds" in seg
                            else (-np.inf, np.inf))
        if "mass" in update:
            mass.append(i)
            gamma_bounds.append(_bounds(spec, seg["mass_bounds"], f"{where}.mass_bounds", names[i], "gamma")
                                if "mass_bounds" in seg else (-np.inf, np.inf))
        elif "mass_bounds" in seg:
            raise spec.error(f"{where}.mass_bounds", f"segment {names[i]!r}: its mass factor is not updated; "
                                                     'add update = ["stiffness", "mass"] or remove mass_bounds')
    bounds = np.array(alpha_bounds + gamma_bounds, dtype=float)
    return np.array(mass, dtype=int), bounds if np.isfinite(bounds).any() else None


def _mesh_model(spec: _Spec, units: str, damping: tuple[float, float]) -> ParametricModel:
    from ..elements import element_family

    length, stress, density = UNITS[units]
    mesh_name = _get(spec, spec.data, "mesh", "", (str,))
    try:
        mf = read_mesh(spec.file("mesh", mesh_name))
    except MeshFileError as exc:
        raise spec.error("mesh", str(exc)) from None
    mesh = mf.mesh
    try:
        family = element_family(mf.cell_type)
    except ValueError as exc:
        raise spec.error("mesh", f"{mf.path.name}: {exc}") from None
    options = _element_options(spec, mf.cell_type)
    n_cells, n_nodes = mesh.n_cells, mesh.n_nodes
    n_total = n_nodes * DOFS_PER_NODE

    def cell_set(name: Any, key: str) -> np.ndarray:
        if not isinstance(name, str):
            raise spec.error(key, f"must be the name of a cell set, got {name!r}")
        if name not in mesh.cell_sets:
            known = ", ".join(sorted(mesh.cell_sets)) or "none"
            raise spec.error(key, f"no cell set {name!r} of volume cells in {mf.path.name} (cell sets: {known})")
        return mesh.cell_sets[name]

    # Materials, one per cell.
    material_of = np.full(n_cells, -1)
    materials = []
    for i, tab in enumerate(_tables(spec, "materials")):
        where = f"materials[{i}]"
        _keys(spec, tab, {"cells", "E", "nu", "rho", "name"}, where)
        E, nu, rho = (_get(spec, tab, k, where, (float,)) for k in ("E", "nu", "rho"))
        try:
            materials.append(Material(E=E * stress, nu=nu, rho=rho * density))
        except ValueError as exc:
            raise spec.error(where, str(exc)) from None
        sets = tab.get("cells")
        names = [sets] if isinstance(sets, str) else sets
        if sets is None:
            cells = np.arange(n_cells)
        elif isinstance(names, list):
            cells = np.unique(np.concatenate([cell_set(n, f"{where}.cells") for n in names]))
        else:
            raise spec.error(f"{where}.cells", f"must be a cell set name or a list of them, got {sets!r}")
        clash = cells[material_of[cells] >= 0]
        if clash.size:
            raise spec.error(f"{where}.cells", f"{clash.size} cells already have the material of "
                                               f"materials[{material_of[clash[0]]}] (e.g. cell {clash[0]})")
        material_of[cells] = i
    if np.any(material_of < 0):
        raise spec.error("materials", f"{int(np.sum(material_of < 0))} cells have no material "
                                      f"(e.g. cell {int(np.flatnonzero(material_of < 0)[0])})")

    # Segments: cell sets, no overlaps; the rest is the fixed remainder.
    seg_tables = _tables(spec, "segments")
    owner = np.full(n_cells, -1)
    seg_names = []
    for i, seg in enumerate(seg_tables):
        where = f"segments[{i}]"
        _keys(spec, seg, {"set", "bounds", "name", "update", "mass_bounds"}, where)
        name = _get(spec, seg, "set", where, (str,))
        cells = cell_set(name, f"{where}.set")
        taken = cells[owner[cells] >= 0]
        if taken.size:
            other = seg_names[owner[taken[0]]]
            raise spec.error(f"{where}.set", f"segments overlap: {taken.size} cells of {name!r} are also in segment "
                                             f"{other!r} (e.g. cell {taken[0]}); a cell belongs to one segment")
        owner[cells] = i
        seg_names.append(_get(spec, seg, "name", where, (str,), name))
    mass_parameters, bounds = _segment_parameters(spec, seg_tables, seg_names)

    # Element matrices and assembly.
    coords = mesh.nodes[mesh.cells] * length
    Ke = np.empty((n_cells, coords.shape[1] * 3, coords.shape[1] * 3))
    Me = np.empty_like(Ke)
    for i, mat in enumerate(materials):
        cells = np.flatnonzero(material_of == i)
        try:
            Ke[cells] = family.element_stiffness(coords[cells], mat.D, **options)
            Me[cells] = family.element_mass(coords[cells], mat.rho)
        except (ValueError, np.linalg.LinAlgError) as exc:
            msg = re.sub(r"element (\d+)", lambda m: f"cell {cells[int(m.group(1))]}", str(exc), count=1)
            raise spec.error("mesh", f"{mf.path.name}: {mf.cell_type} {msg}") from None
    dofs = cell_dofs(mesh.cells)

    fixed = _mesh_supports(spec, mf)
    free = free_dof_map(n_total, fixed)
    _check_rigid_body_modes(spec, mesh.nodes * length, fixed)
    ux = np.zeros(n_total)
    ux[0::DOFS_PER_NODE] = 1.0

    def part(cells):
        K = assemble(Ke[cells], dofs[cells], n_total)
        M = assemble(Me[cells], dofs[cells], n_total)
        return K[free][:, free], M[free][:, free], float(ux @ (M @ ux))

    K_parts, M_parts, masses = zip(*(part(np.flatnonzero(owner == i)) for i in range(len(seg_tables))))
    rest = np.flatnonzero(owner < 0)
    K0 = M0 = None
    rest_mass = 0.0
    if rest.size:
        K0, M0, rest_mass = part(rest)

    tol = _get(spec, spec.data, "point_tolerance", "", (float,), 0.01 * float(np.ptp(mesh.nodes, axis=0).max()))
    locator = _Locator(spec, mf, mesh.nodes, None, tol)
    position = np.full(n_total, -1)
    position[free] = np.arange(free.size)

    def dof_of(node: int, component: int) -> int:
        return int(position[DOFS_PER_NODE * node + component])

    outputs, load, names, placements, exc_name, extra = _sensors_and_excitation(spec, locator, dof_of, free.size)
    mesh.nodes = mesh.nodes * length  # the model's mesh is in m
    model = ParametricModel(
        mesh=mesh, free_dofs=free,
        stiffness_segments=SegmentedMatrix.from_matrices(K_parts, K0),
        mass_segments=SegmentedMatrix.from_matrices(M_parts, M0),
        segment_names=seg_names, damping=damping, segment_masses=list(masses),
        material=materials[0] if len(materials) == 1 else None,
        formulation=options.get("formulation") if mf.cell_type == "hexahedron" else None,
        outputs=outputs, load=load, sensor_names=names, excitation_name=exc_name, n_total_dofs=n_total,
        parameter_bounds=bounds, source=str(spec.path), remainder_mass=rest_mass, placements=placements,
        cell_segment=owner,
        cell_stiffness=_cell_stiffness_of(family, coords, materials, material_of, options),
        mass_parameters=mass_parameters, **extra,
    )
    log.info("%s: %d %s cells, %d nodes, %d free DOFs, %d segments, %d remainder cells", spec.path, n_cells,
             mf.cell_type, n_nodes, free.size, len(seg_names), rest.size)
    return model


def _cell_stiffness_of(family, coords: np.ndarray, materials: list, material_of: np.ndarray, options: dict):
    """``cells -> (len(cells), d, d)`` element stiffness matrices (N/m) of a mesh model's cells, each with its
    material: for effects that stiffen or weaken a set of cells (:mod:`fe_core.closure.effects`)."""
    def cell_stiffness(cells: np.ndarray) -> np.ndarray:
        cells = np.asarray(cells, dtype=int)
        d = coords.shape[1] * DOFS_PER_NODE
        Ke = np.empty((cells.size, d, d))
        for i, mat in enumerate(materials):
            mine = material_of[cells] == i
            if mine.any():
                Ke[mine] = family.element_stiffness(coords[cells[mine]], mat.D, **options)
        return Ke

    return cell_stiffness


def _element_options(spec: _Spec, cell_type: str) -> dict:
    elements = spec.data.get("elements", {})
    if not isinstance(elements, dict) or not all(isinstance(v, dict) for v in elements.values()):
        raise spec.error("elements", "must be a table of tables, e.g. [elements.hexahedron]")
    options = dict(elements.get(cell_type, {}))
    if cell_type == "hexahedron":
        options.setdefault("formulation", "incompatible")
    return options


def _mesh_supports(spec: _Spec, mf: MeshFile) -> np.ndarray:
    mesh = mf.mesh
    fixed = []
    for i, tab in enumerate(_tables(spec, "supports", required=False)):
        where = f"supports[{i}]"
        _keys(spec, tab, {"nodes", "fix", "name"}, where)
        nodes = tab.get("nodes")
        if isinstance(nodes, str):
            if nodes not in mesh.node_sets:
                known = ", ".join(sorted(mesh.node_sets)) or "none"
                raise spec.error(f"{where}.nodes", f"no node set {nodes!r} in {mf.path.name} (node sets: {known})")
            idx = mesh.node_sets[nodes]
        elif isinstance(nodes, list) and nodes and all(isinstance(n, int) and not isinstance(n, bool) for n in nodes):
            try:
                idx = np.array([mf.node_from_file(n) for n in nodes])
            except ValueError as exc:
                raise spec.error(f"{where}.nodes", str(exc)) from None
        else:
            raise spec.error(f"{where}.nodes", f"must be a node set name or a list of node indices, got {nodes!r}")
        if idx.size == 0:
            raise spec.error(f"{where}.nodes", f"node set {nodes!r} has no nodes of the volume mesh")
        fixed.append(_fixed_dofs(spec, tab, where, idx, lambda n, c: DOFS_PER_NODE * n + c))
    return np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, dtype=int)


def _fixed_dofs(spec: _Spec, tab: dict, where: str, nodes: np.ndarray, dof) -> np.ndarray:
    fix = _get(spec, tab, "fix", where, (list,), ["x", "y", "z"])
    comps = []
    for d in fix:
        if not isinstance(d, str) or d.lower() not in ("x", "y", "z"):
            raise spec.error(f"{where}.fix", f"directions are x, y, z; got {d!r}")
        comps.append(DIRECTIONS[d.lower()])
    return np.array([dof(int(n), c) for n in nodes for c in comps], dtype=np.int64)


def _check_rigid_body_modes(spec: _Spec, nodes: np.ndarray, fixed: np.ndarray) -> None:
    """Refuse supports that leave rigid-body motions free, naming them.

    A rigid motion ``u = t + w x (p - c)`` of the whole body is a null vector of
    the constrained stiffness exactly when it vanishes on every fixed DOF, so the
    free rigid motions are the null space of the rigid-body basis restricted to
    the fixed DOFs (6 columns: translations x, y, z, rotations about x, y, z
    through the centroid).
    """
    c = nodes.mean(axis=0)
    p = nodes - c
    n = len(nodes)
    R = np.zeros((n * 3, 6))
    for k in range(3):
        R[k::3, k] = 1.0
    scale = max(float(np.abs(p).max()), 1e-300)
    # rotation about x: (0, -z, y); about y: (z, 0, -x); about z: (-y, x, 0); scaled to unit size
    R[1::3, 3], R[2::3, 3] = -p[:, 2] / scale, p[:, 1] / scale
    R[0::3, 4], R[2::3, 4] = p[:, 2] / scale, -p[:, 0] / scale
    R[0::3, 5], R[1::3, 5] = -p[:, 1] / scale, p[:, 0] / scale
    Rc = R[fixed]
    s = np.linalg.svd(Rc, compute_uv=False) if len(fixed) else np.zeros(0)
    rank = int(np.sum(s > 1e-8 * max(1.0, s.max(initial=0.0))))
    if rank == 6:
        return
    _, _, vt = np.linalg.svd(Rc if len(fixed) else np.zeros((1, 6)))
    null = vt[rank:]
    labels = ["translation x", "translation y", "translation z", "rotation about x", "rotation about y",
              "rotation about z"]
    free = []
    for v in null:
        k = int(np.argmax(np.abs(v)))
        pure = abs(v[k]) > 0.999
        free.append(labels[k] if pure else "a combination of " + ", ".join(
            labels[j] for j in np.flatnonzero(np.abs(v) > 0.05)))
    raise spec.error("supports", f"the structure is not restrained: {6 - rank} rigid-body mode(s) are free "
                                 f"({'; '.join(free)}); fix more directions or nodes")


def _dof_entries(spec: _Spec, locator: _Locator, table: dict, where: str, dof_of, weighted: bool,
                 test_keys: bool = False) -> tuple:
    """(free-DOF indices, weights, placement text, direction) of one sensor or excitation point."""
    allowed = {"node", "point", "direction", "name"} | ({"weight"} if weighted else set())
    allowed |= TEST_KEYS if test_keys else set()
    _keys(spec, table, allowed, where)
    node, placed = locator.node(table, where)
    if "direction" not in table:
        raise spec.error(f"{where}.direction", "is missing (x, y, z or [nx, ny, nz])")
    direction = _direction(spec, table["direction"], f"{where}.direction")
    weight = _get(spec, table, "weight", where, (float,), 1.0) if weighted else 1.0
    rows, values = [], []
    for c in np.flatnonzero(np.abs(direction) > 1e-15):
        row = dof_of(node, int(c))
        if row < 0:
            raise spec.error(where, f"{placed}: direction {'xyz'[c]} of this node is fixed by a support (or not "
                                    "in the DOF table); a sensor or excitation must be on a free DOF")
        rows.append(row)
        values.append(weight * direction[c])
    return rows, values, placed, direction


#: Keys that tie a sensor or an excitation to the test's geometry (UFF58 nodes and directions).
TEST_KEYS = {"test_node", "test_direction"}
_TEST_DIRECTIONS = {"x": 1, "y": 2, "z": 3}


def _test_dof(spec: _Spec, table: dict, where: str, direction: np.ndarray | None) -> tuple[int, int] | None:
    """``(test node, signed UFF58 direction code)`` of a sensor or excitation, or None without ``test_node``.

    ``test_direction`` (``"+z"``, ``"-x"``, or a code 1..3 with a sign) is the direction the test system
    calls this DOF; by default the model direction itself when it is x, y or z.
    """
    if "test_node" not in table:
        if "test_direction" in table:
            raise spec.error(f"{where}.test_direction", "needs test_node (the test's node id)")
        return None
    node = _get(spec, table, "test_node", where, (int,))
    if node < 1:
        raise spec.error(f"{where}.test_node", f"must be a node id >= 1 (UFF58 node 0 means 'none'), got {node}")
    value = table.get("test_direction")
    if value is None:
        axis = None if direction is None else np.flatnonzero(np.abs(direction) > 1e-12)
        if axis is None or axis.size != 1:
            raise spec.error(f"{where}.test_direction", "is needed when the direction is not x, y or z: the test "
                                                       "system's direction of this DOF, e.g. \"+z\" in its local "
                                                       "system")
        code = int(axis[0]) + 1
        return node, code if direction[axis[0]] > 0 else -code
    if isinstance(value, int) and not isinstance(value, bool) and 1 <= abs(value) <= 3:
        return node, value
    if isinstance(value, str):
        text = value.strip().lower()
        sign = -1 if text.startswith("-") else 1
        axis = text.lstrip("+-")
        if axis in _TEST_DIRECTIONS:
            return node, sign * _TEST_DIRECTIONS[axis]
    raise spec.error(f"{where}.test_direction", f"must be +x, -x, +y, -y, +z, -z (or +-1, +-2, +-3), got {value!r}")


def _unique_test_dofs(spec: _Spec, dofs: list, what: str) -> None:
    seen = {}
    for k, dof in enumerate(dofs):
        if dof is None:
            continue
        key = (dof[0], abs(dof[1]))
        if key in seen:
            axis = "xyz"[abs(dof[1]) - 1]
            raise spec.error(f"{what}[{k}].test_node", f"test node {dof[0]} direction {axis} is also that of "
                                                       f"{what}[{seen[key]}]; one {what[:-1]} per test DOF")
        seen[key] = k


def _sensors_and_excitation(spec: _Spec, locator: _Locator, dof_of, n_free: int):
    sensors = _tables(spec, "sensors")
    cols, rows, vals, names, placements, sensor_tests = [], [], [], [], [], []
    for j, tab in enumerate(sensors):
        where = f"sensors[{j}]"
        name = _get(spec, tab, "name", where, (str,), f"sensor {j + 1}")
        if name in names:
            raise spec.error(f"{where}.name", f"sensor name {name!r} is used twice")
        r, v, placed, direction = _dof_entries(spec, locator, tab, where, dof_of, weighted=False, test_keys=True)
        rows += r
        vals += v
        cols += [j] * len(r)
        names.append(name)
        sensor_tests.append(_test_dof(spec, tab, where, direction))
        placements.append(f"sensor {j + 1} {name!r}: {placed}")
    outputs = sp.csr_matrix((vals, (rows, cols)), shape=(n_free, len(sensors)))
    _unique_test_dofs(spec, sensor_tests, "sensors")

    excitations = _tables(spec, "excitations")
    exc_names, exc_tests = [], []
    loads = []
    for k, tab in enumerate(excitations):
        where = f"excitations[{k}]"
        name = _get(spec, tab, "name", where, (str,), f"excitation {k + 1}")
        if name in exc_names:
            raise spec.error(f"{where}.name", f"excitation name {name!r} is used twice")
        exc_names.append(name)
        entries = tab.get("dofs")
        if entries is None:
            entries, base = [tab], where
        elif not (isinstance(entries, list) and entries and all(isinstance(e, dict) for e in entries)):
            raise spec.error(f"{where}.dofs", "must be a non-empty array of tables {node|point, direction, weight}")
        else:
            _keys(spec, tab, {"name", "dofs"} | TEST_KEYS, where)
            base = f"{where}.dofs"
        F = np.zeros(n_free)
        single = entries is not tab.get("dofs")
        direction = None
        for e, entry in enumerate(entries):
            at = base if single else f"{base}[{e}]"
            r, v, placed, direction = _dof_entries(spec, locator, entry, at, dof_of, weighted=True, test_keys=single)
            np.add.at(F, r, v)
            placements.append(f"excitation {exc_names[-1]!r}: {placed}")
        exc_tests.append(_test_dof(spec, tab, where, direction if single else None))
        loads.append(F)
    _unique_test_dofs(spec, exc_tests, "excitations")
    chosen = _get(spec, spec.data, "excitation", "", (str,), exc_names[0] if len(exc_names) == 1 else None)
    if chosen is None:
        raise spec.error("excitation", f"{len(exc_names)} excitations ({', '.join(exc_names)}): name the one "
                                       "that drives the measured FRF")
    if chosen not in exc_names:
        raise spec.error("excitation", f"no excitation {chosen!r} (excitations: {', '.join(exc_names)})")
    extra = dict(excitation_loads=np.column_stack(loads), excitation_names=exc_names, sensor_test_dofs=sensor_tests,
                 excitation_test_dofs=exc_tests)
    return outputs, loads[exc_names.index(chosen)], names, placements, chosen, extra


def _matrices_model(spec: _Spec, units: str, damping: tuple[float, float]) -> ParametricModel:
    length, stress, density = UNITS[units]
    if units != "SI":
        raise spec.error("units", "matrices are taken as given: exported matrices must be in SI (N/m, kg)")
    mat = spec.data["matrices"]
    if not isinstance(mat, dict):
        raise spec.error("matrices", f"must be a table with dofs (and optionally stiffness, mass), got {mat!r}")
    _keys(spec, mat, {"dofs", "stiffness", "mass"}, "matrices")
    dof_path = spec.file("matrices.dofs", _get(spec, mat, "dofs", "matrices", (str,)))

    def matrix(key: str, value: Any) -> sp.csr_matrix:
        if not isinstance(value, str):
            raise spec.error(key, f"must be a file name (.mtx or .npz), got {value!r}")
        try:
            A = read_matrix(spec.file(key, value))
        except MatrixFileError as exc:
            raise spec.error(key, str(exc)) from None
        if A.shape[0] != table.shape[0]:
            raise spec.error(key, f"{value}: matrix is {A.shape[0]} x {A.shape[1]} but the DOF table "
                                  f"{dof_path.name} has {table.shape[0]} rows")
        try:
            check_symmetric_psd(A, value)
        except ValueError as exc:
            raise spec.error(key, str(exc)) from None
        return A

    try:
        table = read_dof_table(dof_path)
    except MatrixFileError as exc:
        raise spec.error("matrices.dofs", str(exc)) from None
    n = table.shape[0]
    seg_tables = _tables(spec, "segments")
    K_full, M_full, names = [], [], []
    for i, seg in enumerate(seg_tables):
        where = f"segments[{i}]"
        _keys(spec, seg, {"name", "stiffness", "mass", "bounds", "update", "mass_bounds"}, where)
        names.append(_get(spec, seg, "name", where, (str,)))
        K_full.append(matrix(f"{where}.stiffness", _get(spec, seg, "stiffness", where, (str,))))
        M_full.append(matrix(f"{where}.mass", _get(spec, seg, "mass", where, (str,))))
    K0 = matrix("matrices.stiffness", mat["stiffness"]) if "stiffness" in mat else None
    M0 = matrix("matrices.mass", mat["mass"]) if "mass" in mat else None
    mass_parameters, bounds = _segment_parameters(spec, seg_tables, names)

    key_of = {(int(nd), int(c)): r for r, (nd, c) in enumerate(table)}
    fixed = []
    for i, tab in enumerate(_tables(spec, "supports", required=False)):
        where = f"supports[{i}]"
        _keys(spec, tab, {"nodes", "fix", "name"}, where)
        nodes = tab.get("nodes")
        if not (isinstance(nodes, list) and nodes and all(isinstance(x, int) and not isinstance(x, bool)
                                                           for x in nodes)):
            raise spec.error(f"{where}.nodes", f"must be a list of node ids of the DOF table, got {nodes!r}")
        missing = sorted(set(nodes) - set(table[:, 0].tolist()))
        if missing:
            raise spec.error(f"{where}.nodes", f"nodes {missing[:5]} are not in the DOF table {dof_path.name}")
        fixed.append(_fixed_dofs(spec, tab, where, np.asarray(nodes), lambda nd, c: key_of.get((nd, c), -1)))
    fixed_rows = np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, dtype=int)
    fixed_rows = fixed_rows[fixed_rows >= 0]
    free = free_dof_map(n, fixed_rows)
    position = np.full(n, -1)
    position[free] = np.arange(free.size)

    def restrict(A):
        return None if A is None else A[free][:, free]

    _check_matrix_rigid_body(spec, K_full, K0, M_full, M0, free)
    ux = (table[:, 1] == 0).astype(float)
    masses = [float(ux @ (M @ ux)) for M in M_full]
    locator = _Locator(spec, None, None, table[:, 0], 0.0)

    def dof_of(node: int, component: int) -> int:
        r = key_of.get((node, component), -1)
        return int(position[r]) if r >= 0 else -1

    outputs, load, snames, placements, exc_name, extra = _sensors_and_excitation(spec, locator, dof_of, free.size)
    return ParametricModel(
        mesh=None, free_dofs=free,
        stiffness_segments=SegmentedMatrix.from_matrices([restrict(K) for K in K_full], restrict(K0)),
        mass_segments=SegmentedMatrix.from_matrices([restrict(M) for M in M_full], restrict(M0)),
        segment_names=names, damping=damping, segment_masses=masses, outputs=outputs, load=load,
        sensor_names=snames, excitation_name=exc_name, n_total_dofs=n, parameter_bounds=bounds,
        source=str(spec.path), remainder_mass=float(ux @ (M0 @ ux)) if M0 is not None else 0.0,
        placements=placements, dof_table=table, mass_parameters=mass_parameters, **extra,
    )


#: Lowest eigenvalue of (K, M), relative to mean(diag K) / mean(diag M), below which it is a rigid-body mode.
RIGID_RTOL = 1e-9


def _check_matrix_rigid_body(spec: _Spec, K_full, K0, M_full, M0, free) -> None:
    """Refuse a singular constrained stiffness (rigid-body modes or mechanisms): the lowest eigenvalues."""
    import scipy.sparse.linalg as spla

    K = sum(K_full[1:], K_full[0]) + (K0 if K0 is not None else 0)
    M = sum(M_full[1:], M_full[0]) + (M0 if M0 is not None else 0)
    K, M = sp.csc_matrix(K[free][:, free]), sp.csc_matrix(M[free][:, free])
    scale = float(K.diagonal().mean() / max(M.diagonal().mean(), 1e-300))
    k = min(6, K.shape[0] - 2)
    if k < 1:
        return
    try:
        vals = spla.eigsh(K, k=k, M=M, sigma=-1e-3 * scale, which="LM", v0=np.ones(K.shape[0]),
                          return_eigenvectors=False)
    except (RuntimeError, ValueError) as exc:  # a singular M, for instance
        raise spec.error("matrices", f"cannot compute the lowest eigenvalues of (K, M): {exc}") from None
    vals = np.sort(vals)
    zero = vals < RIGID_RTOL * scale
    if np.any(zero):
        freqs = np.sqrt(np.clip(vals, 0, None)) / (2 * np.pi)
        raise spec.error("supports", f"the structure is not restrained: {int(zero.sum())} rigid-body mode(s) or "
                                     f"mechanism(s); lowest natural frequencies {np.round(freqs, 6).tolist()} Hz "
                                     f"(eigenvalues {vals[:int(zero.sum()) + 1].tolist()})")
