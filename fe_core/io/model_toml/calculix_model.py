"""A model file for a CalculiX deck (``solver = "calculix"``), route A: segments are ``*ELSET`` names whose
section's Young's modulus (alpha) and density (gamma) are the parameters; ccx exports the matrices
(:mod:`fe_core.io.calculix.segments`) and everything else runs in-process as for a matrices model::

    solver = "calculix"
    deck = "panel.inp"                 # the deck's *BOUNDARY holds the supports; units as in the deck (SI)
    solver_timeout = 300.0             # s per ccx run (default 600)
    include_paths = ["../common"]      # folders *INCLUDE may read besides the model's own (default none)

    [[segments]]
    set = "SKIN_1"                     # an *ELSET with one *SOLID/*SHELL SECTION
    name = "skin 1"                    # optional (default: the set)
    bounds = [-0.5, 0.5]
    update = ["stiffness", "mass"]     # as for other models

    [[sensors]]
    node = 17                          # a deck node id; or nset = "TIP" (one node), or point = [x, y, z]
    direction = "z"

A sensor or excitation on a shell node is the mean of ccx's expanded nodes' rows (as ccx itself
reports a shell node's displacement and shares a point load).
"""

from __future__ import annotations

import copy

import numpy as np
import scipy.sparse as sp

from ...assembly import SegmentedMatrix
from ...model import ParametricModel
from ..calculix import CcxError, DeckError, Segment, read_deck, segment_matrices
from ..calculix.results import ResultError
from ..calculix.vtu import deck_view
from .sensors import _Locator, _point_placement, _sensors_and_excitation
from .spec import _get, _keys, _segment_parameters, _Spec, _tables

__all__ = ["DEFAULT_TIMEOUT"]

#: Seconds a ccx run may take unless the model file says ``solver_timeout``.
DEFAULT_TIMEOUT = 600.0


class _DeckLocator(_Locator):
    """Sensors and excitations by deck node id or nearest deck node to a point."""

    def __init__(self, spec: _Spec, deck, tolerance: float):
        ids = np.array(sorted(deck.nodes), dtype=np.int64)
        super().__init__(spec, None, np.array([deck.nodes[i] for i in ids], float).reshape(-1, 3), ids, tolerance)
        self.deck = deck

    def node(self, table: dict, where: str) -> tuple[int, str]:
        spec = self.spec
        if ("node" in table) == ("point" in table):
            raise spec.error(f"{where}.node", "give exactly one of 'node' (a deck node id), 'nset' or 'point'")
        if "node" in table:
            value = _get(spec, table, "node", where, (int,))
            if value not in self.deck.nodes:
                raise spec.error(f"{where}.node", f"node {value} is not a node of the deck {self.deck.path}")
            return int(value), f"node {value}"
        i, placed = super().node(table, where)
        return int(self.node_ids[i]), placed.replace(f"nearest node {i}", f"nearest node {int(self.node_ids[i])}")


def _resolve_nsets(spec: _Spec, deck) -> None:
    """Replace ``nset = "NAME"`` entries of sensors and excitations by the set's single node; refuse node ids
    absent from the deck (before any ccx run)."""
    data = copy.deepcopy(spec.data)
    for key in ("sensors", "excitations"):
        for t, tab in enumerate(data.get(key, []) if isinstance(data.get(key), list) else []):
            entries = [(f"{key}[{t}]", tab)]
            if isinstance(tab, dict) and isinstance(tab.get("dofs"), list):
                entries += [(f"{key}[{t}].dofs[{e}]", d) for e, d in enumerate(tab["dofs"])]
            for where, entry in entries:
                node = entry.get("node") if isinstance(entry, dict) else None
                if isinstance(node, int) and not isinstance(node, bool) and node not in deck.nodes:
                    raise spec.error(f"{where}.node", f"node {node} is not a node of the deck {deck.path}")
                if not isinstance(entry, dict) or "nset" not in entry:
                    continue
                name = entry.pop("nset")
                if "node" in entry or "point" in entry:
                    raise spec.error(f"{where}.nset", "give one of node, nset or point")
                members = sorted(set(deck.nsets.get(str(name).upper(), [])))
                if str(name).upper() not in deck.nsets:
                    raise spec.error(f"{where}.nset", f"*NSET {name!r} is not in the deck {deck.path}")
                if len(members) != 1:
                    raise spec.error(f"{where}.nset", f"*NSET {name!r} has {len(members)} nodes; a sensor or "
                                                      "excitation point needs a set of one node")
                entry["node"] = members[0]
    spec.data = data


def _segments(spec: _Spec, deck) -> tuple[list[Segment], list[dict]]:
    tables = _tables(spec, "segments")
    out = []
    for i, seg in enumerate(tables):
        where = f"segments[{i}]"
        _keys(spec, seg, {"set", "name", "bounds", "update", "mass_bounds"}, where)
        elset = _get(spec, seg, "set", where, (str,))
        if elset.upper() not in deck.elsets:
            raise spec.error(f"{where}.set", f"*ELSET {elset!r} is not in the deck {deck.path}")
        try:
            section = deck.section_of(elset)
            modulus = deck.material_number(section, "*ELASTIC")
            mat = (deck.cards[section].param("MATERIAL") or "").upper()
            density = deck.material_number(section, "*DENSITY") if "*DENSITY" in deck.material_cards[mat] else None
            deck.number(modulus)
        except DeckError as exc:
            raise spec.error(f"{where}.set", str(exc)) from None
        if density is None and "mass" in seg.get("update", []):
            raise spec.error(f"{where}.update", f"the material of ELSET={elset} has no *DENSITY in {deck.path}")
        name = _get(spec, seg, "name", where, (str,), elset)
        if any(s.name == name for s in out):
            raise spec.error(f"{where}.name", f"segment name {name!r} is used twice")
        out.append(Segment(name, elset, section, modulus, density))
    return out, tables


def _check_restrained(spec: _Spec, K, deck_path) -> None:
    """Refuse a singular stiffness (a deck without enough *BOUNDARY): its sparse LU fails or is inaccurate."""
    import scipy.sparse.linalg as spla

    K = sp.csc_matrix(K)
    b = K @ np.ones(K.shape[0])
    try:
        x = spla.splu(K).solve(b)
        ok = np.all(np.isfinite(x)) and np.linalg.norm(x - 1.0) < 1e-3 * np.sqrt(K.shape[0])
    except RuntimeError:
        ok = False
    if not ok:
        raise spec.error("deck", f"{deck_path}: the stiffness ccx exports is singular: the structure is not "
                                 "restrained (add *BOUNDARY cards) or has a mechanism")


def _read_deck_settings(spec: _Spec, units: str):
    """(deck, solver_timeout) of a ``solver = "calculix"`` model file, checked (routes A and B)."""
    _point_placement(spec, mesh=False)   # a deck's points go to their nearest node
    if units != "SI":
        raise spec.error("units", "a deck is taken in its own units; give its numbers in SI (N, m, kg, s)")
    solver = _get(spec, spec.data, "solver", "", (str,))
    if solver != "calculix":
        raise spec.error("solver", f"unknown solver {solver!r}; the supported one is \"calculix\"")
    deck_path = spec.file("deck", _get(spec, spec.data, "deck", "", (str,)))
    includes = _get(spec, spec.data, "include_paths", "", (list,), [])
    allowed = []
    for k, p in enumerate(includes):
        if not isinstance(p, str):
            raise spec.error(f"include_paths[{k}]", f"must be a folder name, got {p!r}")
        allowed.append(spec.file(f"include_paths[{k}]", p))
    timeout = _get(spec, spec.data, "solver_timeout", "", (float,), DEFAULT_TIMEOUT)
    if not timeout > 0:
        raise spec.error("solver_timeout", f"must be > 0 seconds, got {timeout}")
    if "supports" in spec.data:
        raise spec.error("supports", "a deck's supports are its *BOUNDARY cards; remove [[supports]]")
    try:
        deck = read_deck(deck_path, allowed)
    except DeckError as exc:
        raise spec.error("deck", str(exc)) from None
    return deck, timeout


def _calculix_model(spec: _Spec, units: str, damping: tuple[float, float]) -> ParametricModel:
    deck, timeout = _read_deck_settings(spec, units)
    segments, tables = _segments(spec, deck)
    _resolve_nsets(spec, deck)
    names = [s.name for s in segments]
    mass_parameters, bounds = _segment_parameters(spec, tables, names)
    try:
        K_seg, M_seg, K0, M0, labels = segment_matrices(deck, segments, timeout)
    except (CcxError, ResultError, ValueError) as exc:
        raise spec.error("deck", str(exc)) from None
    n = labels.shape[0]
    _check_restrained(spec, sum(K_seg, K0), deck.path)

    pairs = {}
    for r, (node, d) in enumerate(labels):
        pairs.setdefault((int(node), int(d) - 1), []).append(r)
    keys = list(pairs)
    index = {k: j for j, k in enumerate(keys)}
    rows = [r for k in keys for r in pairs[k]]
    cols = [index[k] for k in keys for _ in pairs[k]]
    vals = [1.0 / len(pairs[k]) for k in keys for _ in pairs[k]]
    average = sp.csr_matrix((vals, (rows, cols)), shape=(n, len(keys)))

    def dof_of(node: int, component: int) -> int:
        return n + index[(node, component)] if (node, component) in index else -1

    locator = _DeckLocator(spec, deck, _get(spec, spec.data, "point_tolerance", "", (float,), 1e-6))
    outputs, load, snames, placements, exc_name, extra = _sensors_and_excitation(spec, locator, dof_of,
                                                                                 n + len(keys))

    def fold(A):
        A = sp.csr_matrix(A) if sp.issparse(A) else np.asarray(A)
        return A[:n] + average @ A[n:]

    outputs = sp.csr_matrix(fold(outputs))
    load = np.asarray(fold(load)).ravel()
    extra["excitation_loads"] = np.asarray(fold(extra["excitation_loads"]))
    table = np.column_stack([labels[:, 0], labels[:, 1] - 1])
    ux = (table[:, 1] == 0).astype(float)
    masses = [float(ux @ (M @ ux)) for M in M_seg]
    # The deck's coordinates of the nodes the DOF table names (NaN for a node ccx made, not in the deck): the
    # closure places nodal effects and measures their spread with them, as for a matrices model's node table.
    ids = np.unique(table[:, 0])
    coordinates = np.array([deck.nodes.get(int(i), (np.nan,) * 3) for i in ids], float)
    model = ParametricModel(
        mesh=None, free_dofs=np.arange(n),
        stiffness_segments=SegmentedMatrix.from_matrices(K_seg, K0),
        mass_segments=SegmentedMatrix.from_matrices(M_seg, M0),
        segment_names=names, damping=damping, segment_masses=masses, outputs=outputs, load=load,
        sensor_names=snames, excitation_name=exc_name, n_total_dofs=n, parameter_bounds=bounds,
        source=str(spec.path), remainder_mass=float(ux @ (M0 @ ux)), placements=placements, dof_table=table,
        mass_parameters=mass_parameters, node_coordinates=coordinates, **extra,
    )
    model.deck_view = deck_view(deck, [seg.elset for seg in segments], labels)   # for model.vtu
    return model
