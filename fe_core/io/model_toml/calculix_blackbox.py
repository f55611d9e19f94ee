"""A model file for route B (ccx as a black box): ``[[parameters]]`` are relative factors on numbers of the
deck, for what is not linear in K or M (shell thicknesses, spring stiffnesses, beam section sizes)::

    solver = "calculix"
    deck = "panel.inp"
    solver_timeout = 120.0             # s per ccx run (default 600)
    n_modes = 40                       # modes of ccx's modal steady state (default 40; well above the band)

    [[parameters]]                     # a *SHELL SECTION's thickness (first number of its first data line)
    name = "t_root"
    kind = "shell_thickness"
    elset = "ROOT"
    bounds = [-0.3, 0.3]

    [[parameters]]                     # generally: a number named by card, set (or material), line and field
    name = "k_mount"
    card = "*SPRING"
    elset = "MOUNT"                    # the card's ELSET=; or material = "STEEL" for a card of that material
    line = 2                           # data line of the card, 1-based (default 1)
    field = 1                          # field of that line, 1-based (default 1)

Every parameter must name exactly one non-zero number of the deck; anything else is refused before any ccx
run, naming the model file's key and the deck's file and line. Sensors and excitations are given as for
route A (``node``, ``nset`` or ``point``; a shell node's displacement is what ccx prints for it).
"""

from __future__ import annotations

import numpy as np

from ..calculix import DeckError
from ..calculix.blackbox_model import BlackBoxDeckModel
from ..calculix.deck import NumberRef
from .calculix_model import _DeckLocator, _read_deck_settings, _resolve_nsets
from .sensors import _sensors_and_excitation
from .spec import _get, _keys, _Spec, _tables

__all__ = ["PARAMETER_KINDS"]

#: ``kind`` shortcuts: (card, data line, field), 1-based.
PARAMETER_KINDS = {"shell_thickness": ("*SHELL SECTION", 1, 1), "number": (None, 1, 1)}


def _card(spec: _Spec, deck, table: dict, where: str, keyword: str) -> int:
    """Index of the one card ``keyword`` the table's ``elset`` / ``material`` selects."""
    hits = [i for i, c in enumerate(deck.cards[:deck.first_step]) if c.keyword == keyword]
    if not hits:
        raise spec.error(f"{where}.card", f"the deck {deck.path} has no {keyword} card")
    if "elset" in table and "material" in table:
        raise spec.error(f"{where}.material", "give one of elset or material")
    if "elset" in table:
        elset = _get(spec, table, "elset", where, (str,))
        if elset.upper() not in deck.elsets:
            raise spec.error(f"{where}.elset", f"*ELSET {elset!r} is not in the deck {deck.path}")
        hits = [i for i in hits if (deck.cards[i].param("ELSET") or "").upper() == elset.upper()]
        what = f"{keyword} with ELSET={elset}"
        key = "elset"
    elif "material" in table:
        material = _get(spec, table, "material", where, (str,)).upper()
        if material not in deck.materials:
            raise spec.error(f"{where}.material", f"material {material!r} is not in the deck {deck.path}")
        at = deck.material_cards[material].get(keyword)
        hits = [] if at is None else [at]
        what = f"{keyword} of material {material}"
        key = "material"
    else:
        what, key = keyword, "card"
    if not hits:
        raise spec.error(f"{where}.{key}", f"the deck {deck.path} has no {what}")
    if len(hits) > 1:
        lines = ", ".join(deck.cards[i].where() for i in hits[:4])
        raise spec.error(f"{where}.{key}", f"{len(hits)} cards {what} ({lines}): name one (elset or material)")
    return hits[0]


def _parameters(spec: _Spec, deck) -> tuple[list[NumberRef], list[str], np.ndarray]:
    refs, names, bounds = [], [], []
    for i, tab in enumerate(_tables(spec, "parameters")):
        where = f"parameters[{i}]"
        _keys(spec, tab, {"name", "kind", "card", "elset", "material", "line", "field", "bounds"}, where)
        kind = _get(spec, tab, "kind", where, (str,), "number" if "card" in tab else "shell_thickness")
        if kind not in PARAMETER_KINDS:
            raise spec.error(f"{where}.kind", f"unknown kind {kind!r}; choose one of {', '.join(PARAMETER_KINDS)}")
        card, line, field = PARAMETER_KINDS[kind]
        if card is not None and "card" in tab:
            raise spec.error(f"{where}.card", f"kind = {kind!r} names its card ({card}); remove card or kind")
        card = card or " ".join(_get(spec, tab, "card", where, (str,)).upper().split())
        if not card.startswith("*"):
            raise spec.error(f"{where}.card", f"must be a keyword such as \"*SPRING\", got {card!r}")
        line = _get(spec, tab, "line", where, (int,), line)
        field = _get(spec, tab, "field", where, (int,), field)
        for key, value in (("line", line), ("field", field)):
            if value < 1:
                raise spec.error(f"{where}.{key}", f"must be >= 1 (1-based), got {value}")
        ref = NumberRef(_card(spec, deck, tab, where, card), line - 1, field - 1)
        try:
            value = deck.number(ref)
        except DeckError as exc:
            raise spec.error(f"{where}.{'field' if 'no data line' not in str(exc) else 'line'}", str(exc)) from None
        if value == 0.0:
            raise spec.error(f"{where}.field", f"{deck.cards[ref.card].where(ref.row)}: the number is 0: a relative "
                                               "factor on it changes nothing")
        if ref in refs:
            raise spec.error(where, f"{deck.cards[ref.card].where(ref.row)}: the same number as "
                                    f"parameters[{refs.index(ref)}]")
        name = _get(spec, tab, "name", where, (str,), f"{card[1:].lower().replace(' ', '_')}_{i + 1}")
        if name in names:
            raise spec.error(f"{where}.name", f"parameter name {name!r} is used twice")
        b = _get(spec, tab, "bounds", where, (list,), [-np.inf, np.inf])   # none: the run's lower/upper
        if "bounds" in tab and not (len(b) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in b)
                and -1.0 < b[0] < b[1]):
            raise spec.error(f"{where}.bounds", f"must be [low, high] with -1 < low < high, got {b!r}")
        refs.append(ref)
        names.append(name)
        bounds.append([float(b[0]), float(b[1])])
    return refs, names, np.array(bounds, float)


def _blackbox_model(spec: _Spec, units: str, damping: tuple[float, float]) -> BlackBoxDeckModel:
    if "segments" in spec.data:
        raise spec.error("segments", "give [[parameters]] (route B, factors on numbers of the deck) or "
                                     "[[segments]] (route A, moduli and densities), not both")
    deck, timeout = _read_deck_settings(spec, units)
    n_modes = _get(spec, spec.data, "n_modes", "", (int,), 40)
    if n_modes < 1:
        raise spec.error("n_modes", f"must be >= 1, got {n_modes}")
    refs, names, bounds = _parameters(spec, deck)
    _resolve_nsets(spec, deck)
    node_ids = np.array(sorted(deck.nodes), dtype=np.int64)
    block = {int(n): k for k, n in enumerate(node_ids)}

    def dof_of(node: int, component: int) -> int:
        return 3 * block[int(node)] + component if int(node) in block else -1

    locator = _DeckLocator(spec, deck, _get(spec, spec.data, "point_tolerance", "", (float,), 1e-6))
    outputs, load, snames, placements, exc_name, extra = _sensors_and_excitation(spec, locator, dof_of,
                                                                                 3 * node_ids.size)
    return BlackBoxDeckModel(
        deck=deck, numbers=refs, segment_names=names, parameter_bounds=bounds, node_ids=node_ids,
        outputs=outputs.tocsr(), load=np.asarray(load, float), excitation_loads=extra["excitation_loads"],
        sensor_names=snames, excitation_name=exc_name, excitation_names=extra["excitation_names"],
        sensor_test_dofs=extra["sensor_test_dofs"], excitation_test_dofs=extra["excitation_test_dofs"],
        placements=placements, damping=damping, n_modes=n_modes, timeout=timeout, source=str(spec.path))
