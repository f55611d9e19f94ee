"""Sensors and excitations of a model file: directions, nodes found by index or nearest point
(:class:`_Locator`), or with ``point_placement = "interpolate"`` a mesh model's points read through the
shape functions of the element holding them (:mod:`fe_core.elements.locate`), the output vectors and loads
on the free DOFs, and the test's node and direction of each (UFF58, :data:`TEST_KEYS`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..matrices import DIRECTIONS
from ..mesh_file import MeshFile
from .spec import _get, _keys, _Spec, _tables

__all__ = ["TEST_KEYS", "PLACEMENTS"]

#: Values of the top-level ``point_placement`` key: a ``point`` goes to its nearest node (the default), or is
#: read through the shape functions of the mesh element holding it.
PLACEMENTS = ("nearest", "interpolate")

#: Shape-function weights below this fraction of the largest are dropped (a point at a node reads that node).
WEIGHT_RTOL = 1e-12


def _point_placement(spec: _Spec, mesh: bool) -> str:
    """The model file's ``point_placement``; ``"interpolate"`` only for a mesh model (``mesh = ...``)."""
    value = _get(spec, spec.data, "point_placement", "", (str,), "nearest")
    if value not in PLACEMENTS:
        raise spec.error("point_placement", f"unknown value {value!r}; use \"nearest\" (a point goes to its "
                                            "nearest node, the default) or \"interpolate\" (read through the "
                                            "shape functions of the mesh element holding it)")
    if value == "interpolate" and not mesh:
        raise spec.error("point_placement", "\"interpolate\" reads points through the element shape functions "
                                            "of a mesh model (mesh = ...); this model's matrices come from a "
                                            "solver deck or files without elements, so its points go to their "
                                            "nearest node: leave the key out or set \"nearest\"")
    return value


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
    placement: str = "nearest"     # point_placement: "interpolate" needs cells and cell_type (mesh models)
    cells: np.ndarray | None = None
    cell_type: str | None = None
    _cell_locator: Any = field(default=None, init=False, repr=False)

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
        point, dist, i = self._point(table, where)
        if dist[i] > self.tolerance:
            raise spec.error(f"{where}.point", f"the nearest node to {point} is {dist[i]:.6g} (mesh units) away at "
                                               f"{self.nodes[i].tolist()}, beyond point_tolerance = {self.tolerance:.6g}")
        return i, f"nearest node {i} at {dist[i]:.3g} from {point}"

    def _point(self, table: dict, where: str) -> tuple[list, np.ndarray, int]:
        """(the checked ``point``, its distance to every node, the nearest node)."""
        point = table["point"]
        if not (isinstance(point, list) and len(point) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in point)):
            raise self.spec.error(f"{where}.point", f"must be [x, y, z], got {point!r}")
        if self.nodes is None:
            raise self.spec.error(f"{where}.point", "a matrices model has no node coordinates: give 'node'")
        dist = np.linalg.norm(self.nodes - np.asarray(point, float), axis=1)
        return point, dist, int(np.argmin(dist))

    def weights(self, table: dict, where: str) -> tuple[list[tuple[int, float]], str, int, bool]:
        """``([(node, weight), ...], placement sentence, nearest node, interpolated)`` of an entry: one node
        with weight 1 (``node``, or ``point`` with ``"nearest"``), or the shape functions of the element
        holding the point (``"interpolate"``; weights below :data:`WEIGHT_RTOL` of the largest dropped)."""
        if self.placement != "interpolate" or "point" not in table or "node" in table:
            node, placed = self.node(table, where)
            return [(node, 1.0)], placed, node, False
        from ...elements.locate import CellLocator

        point, dist, i = self._point(table, where)
        if self._cell_locator is None:
            self._cell_locator = CellLocator(self.cell_type, self.nodes, self.cells)
        hit = self._cell_locator.locate(np.asarray(point, float), margin=self.tolerance)
        if hit is None or hit.outside > self.tolerance:
            how = "no element comes near it" if hit is None else (f"the nearest element {hit.cell} is "
                                                                  f"{hit.outside:.6g} (mesh units) away")
            raise self.spec.error(f"{where}.point", f"{point} is outside the mesh: {how}, beyond point_tolerance "
                                                    f"= {self.tolerance:.6g} (nearest node {i} at {dist[i]:.6g})")
        w = hit.weights
        keep = np.abs(w) >= WEIGHT_RTOL * np.abs(w).max()
        if not keep.all():
            w = w[keep] / w[keep].sum()   # the shape functions sum to one
        nodes = self.cells[hit.cell][keep]
        moved = f", {hit.outside:.3g} outside the mesh" if hit.outside > 1e-9 * self.tolerance else ""
        placed = (f"at node {int(nodes[0])} ({dist[i]:.3g} from {point}{moved})" if nodes.size == 1 else
                  f"between nodes: element {hit.cell} at distance {dist[i]:.3g} from nearest node {i} ({point}{moved})")
        return [(int(n), float(v)) for n, v in zip(nodes, w)], placed, i, True


def _dof_entries(spec: _Spec, locator: _Locator, table: dict, where: str, dof_of, weighted: bool,
                 test_keys: bool = False) -> tuple:
    """(free-DOF indices, weights, placement text, direction, nearest node) of one sensor or excitation point.

    A node's DOF fixed by a support is refused; a point read through an element skips its fixed DOFs (their
    displacement is zero) and is refused only when all of them are fixed."""
    allowed = {"node", "point", "direction", "name"} | ({"weight"} if weighted else set())
    allowed |= TEST_KEYS if test_keys else set()
    _keys(spec, table, allowed, where)
    at, placed, nearest, interpolated = locator.weights(table, where)
    if "direction" not in table:
        raise spec.error(f"{where}.direction", "is missing (x, y, z or [nx, ny, nz])")
    direction = _direction(spec, table["direction"], f"{where}.direction")
    weight = _get(spec, table, "weight", where, (float,), 1.0) if weighted else 1.0
    rows, values = [], []
    for node, w in at:
        for c in np.flatnonzero(np.abs(direction) > 1e-15):
            row = dof_of(node, int(c))
            if row < 0 and interpolated:
                continue
            if row < 0:
                raise spec.error(where, f"{placed}: direction {'xyz'[c]} of this node is fixed by a support (or "
                                        "not in the DOF table); a sensor or excitation must be on a free DOF")
            rows.append(row)
            values.append(weight * w * direction[c])
    if not rows:
        raise spec.error(where, f"{placed}: every DOF of this element's nodes along the direction is fixed by a "
                                "support; a sensor or excitation must move")
    return rows, values, placed, direction, nearest


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
    cols, rows, vals, names, placements, sensor_tests, sensor_nodes = [], [], [], [], [], [], []
    for j, tab in enumerate(sensors):
        where = f"sensors[{j}]"
        name = _get(spec, tab, "name", where, (str,), f"sensor {j + 1}")
        if name in names:
            raise spec.error(f"{where}.name", f"sensor name {name!r} is used twice")
        r, v, placed, direction, nearest = _dof_entries(spec, locator, tab, where, dof_of, weighted=False,
                                                        test_keys=True)
        sensor_nodes.append(nearest)
        rows += r
        vals += v
        cols += [j] * len(r)
        names.append(name)
        sensor_tests.append(_test_dof(spec, tab, where, direction))
        placements.append(f"sensor {j + 1} {name!r}: {placed}")
    outputs = sp.csr_matrix((vals, (rows, cols)), shape=(n_free, len(sensors)))
    _unique_test_dofs(spec, sensor_tests, "sensors")

    excitations = _tables(spec, "excitations")
    exc_names, exc_tests, exc_nodes = [], [], {}
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
            r, v, placed, direction, nearest = _dof_entries(spec, locator, entry, at, dof_of, weighted=True,
                                                            test_keys=single)
            exc_nodes.setdefault(name, []).append((nearest, (direction * _get(spec, entry, "weight", at, (float,),
                                                                              1.0)).tolist()))
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
    if locator.placement == "interpolate":   # sensor mass and gain effects, the report: the nearest node
        extra["sensor_nodes"] = np.array(sensor_nodes, dtype=int)
        extra["excitation_nodes"] = exc_nodes
    return outputs, loads[exc_names.index(chosen)], names, placements, chosen, extra
