"""A model file with exported matrices: the DOF table, segment and remainder matrices (checked symmetric
positive semi-definite), supports by node id (refused if the constrained stiffness is singular), assembled
into a :class:`fe_core.model.ParametricModel` (:func:`_matrices_model`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ...assembly import SegmentedMatrix, free_dof_map
from ...model import ParametricModel
from ..matrices import MatrixFileError, check_symmetric_psd, read_dof_table, read_matrix, read_node_table
from .sensors import _Locator, _point_placement, _sensors_and_excitation
from .spec import UNITS, _fixed_dofs, _get, _keys, _segment_parameters, _Spec, _tables

__all__ = ["RIGID_RTOL"]


def _matrices_model(spec: _Spec, units: str, damping: tuple[float, float]) -> ParametricModel:
    length, stress, density = UNITS[units]
    _point_placement(spec, mesh=False)
    if units != "SI":
        raise spec.error("units", "matrices are taken as given: exported matrices must be in SI (N/m, kg)")
    mat = spec.data["matrices"]
    if not isinstance(mat, dict):
        raise spec.error("matrices", f"must be a table with dofs (and optionally stiffness, mass), got {mat!r}")
    _keys(spec, mat, {"dofs", "stiffness", "mass", "nodes"}, "matrices")
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
    coordinates = _node_coordinates(spec, mat, table, dof_path.name)
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
        placements=placements, dof_table=table, mass_parameters=mass_parameters, node_coordinates=coordinates,
        **extra,
    )


def _node_coordinates(spec: _Spec, mat: dict, table: np.ndarray, dof_name: str) -> np.ndarray | None:
    """``matrices.nodes``: the coordinates of every node of the DOF table, shape (k, 3), m, in the order of
    the table's ascending node ids (:func:`fe_core.closure.effects.base.node_rows`); None without the key.
    Nodes the DOF table does not name are ignored; a node of the DOF table without coordinates is refused."""
    if "nodes" not in mat:
        return None
    path = spec.file("matrices.nodes", _get(spec, mat, "nodes", "matrices", (str,)))
    try:
        ids, xyz = read_node_table(path)
    except MatrixFileError as exc:
        raise spec.error("matrices.nodes", str(exc)) from None
    nodes = np.unique(table[:, 0])
    at = np.clip(np.searchsorted(ids, nodes), 0, max(ids.size - 1, 0))
    missing = nodes[ids[at] != nodes] if ids.size else nodes
    if missing.size:
        raise spec.error("matrices.nodes", f"{path.name}: no coordinates for {missing.size} node(s) of the DOF "
                                           f"table {dof_name}, e.g. node(s) {missing[:5].tolist()}")
    return xyz[at]


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
