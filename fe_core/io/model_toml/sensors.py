"""Sensors and excitations of a model file: directions, nodes found by index or nearest point
(:class:`_Locator`), the output vectors and loads on the free DOFs, and the test's node and direction of
each (UFF58, :data:`TEST_KEYS`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..matrices import DIRECTIONS
from ..mesh_file import MeshFile
from .spec import _get, _keys, _Spec, _tables

__all__ = ["TEST_KEYS"]


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
