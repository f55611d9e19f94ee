"""A CalculiX / Abaqus input deck (``.inp``): its cards with file and line, the model data the updating
needs (nodes, elements, node and element sets, materials, sections), and a modified copy written out.

Plain text handling, no solver: :func:`read_deck` parses ``*NODE``, ``*ELEMENT``, ``*NSET``, ``*ELSET``
(lists, set names, ``GENERATE``), ``*MATERIAL`` with ``*ELASTIC`` and ``*DENSITY``, ``*SOLID SECTION``,
``*SHELL SECTION``, ``*BEAM SECTION``, ``*SPRING`` and ``*BOUNDARY``, and follows ``*INCLUDE, INPUT=...``;
an included file outside the allowed folders (by default the deck's own folder) is refused. Every other
card is kept as it is. :meth:`Deck.text` writes the model part (includes inlined) with some numbers or
keyword parameters replaced, extra cards added, and the deck's steps or new ones.

A number of the deck is a :class:`NumberRef`: a card, one of its data lines and a field (0-based).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Card", "Deck", "DeckError", "NumberRef", "read_deck", "SECTION_KEYWORDS"]

#: Section cards: the element set they cover is the ``ELSET`` parameter.
SECTION_KEYWORDS = ("*SOLID SECTION", "*SHELL SECTION", "*BEAM SECTION", "*MEMBRANE SECTION")


class DeckError(ValueError):
    """A deck that cannot be used; the message names the file and line."""


@dataclass
class Card:
    """One keyword card: ``*KEYWORD, PARAM=VALUE, ...`` and its data lines."""

    keyword: str                      # upper case, single spaces: "*SHELL SECTION"
    params: dict                      # upper-case keys; values as written (stripped); flags map to ""
    file: Path
    line: int                         # 1-based line of the keyword
    data: list = field(default_factory=list)   # [(text, file, line)], continuation lines joined

    def where(self, k: int | None = None) -> str:
        if k is None:
            return f"{self.file}:{self.line}"
        return f"{self.data[k][1]}:{self.data[k][2]}"

    def param(self, name: str, default: str | None = None) -> str | None:
        return self.params.get(name.upper(), default)

    def fields(self, k: int) -> list[str]:
        return [f.strip() for f in self.data[k][0].split(",")]


@dataclass(frozen=True)
class NumberRef:
    """A number of the deck: card index, data-line index, field index (0-based)."""

    card: int
    row: int
    field: int


def _parse_keyword(text: str, path: Path, lineno: int) -> Card:
    parts = [p.strip() for p in text.split(",")]
    keyword = " ".join(parts[0].upper().split())
    params = {}
    for p in parts[1:]:
        if not p:
            continue
        key, _, value = p.partition("=")
        params[" ".join(key.upper().split())] = value.strip()
    return Card(keyword, params, path, lineno)


def _inside(path: Path, folders: list[Path]) -> bool:
    path = path.resolve()
    return any(path == f or f in path.parents for f in (g.resolve() for g in folders))


def _read_cards(path: Path, allowed: list[Path], cards: list[Card], seen: tuple) -> None:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise DeckError(f"{path}: cannot read the deck ({exc.strerror})") from None
    card = None
    for lineno, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text or text.startswith("**"):
            continue
        if text.startswith("*"):
            card = _parse_keyword(text, path, lineno)
            if card.keyword == "*INCLUDE":
                name = card.param("INPUT")
                if not name:
                    raise DeckError(f"{path}:{lineno}: *INCLUDE needs INPUT=<file>")
                inc = Path(name.strip("\"'"))
                inc = inc if inc.is_absolute() else path.parent / inc
                if not _inside(inc, allowed):
                    raise DeckError(f"{path}:{lineno}: *INCLUDE of {str(inc)!r} is outside the model's folder "
                                    f"{str(allowed[0])!r}; allow its folder in the model file "
                                    "(include_paths = [...]) if it is meant")
                if not inc.exists():
                    raise DeckError(f"{path}:{lineno}: *INCLUDE file {str(inc)!r} does not exist")
                if inc.resolve() in seen:
                    raise DeckError(f"{path}:{lineno}: *INCLUDE of {str(inc)!r} includes itself")
                _read_cards(inc, allowed, cards, seen + (inc.resolve(),))
                card = None
                continue
            cards.append(card)
            continue
        if card is None:
            raise DeckError(f"{path}:{lineno}: data line {text[:40]!r} before any keyword card")
        if card.data and card.keyword == "*ELEMENT" and card.data[-1][0].rstrip().endswith(","):
            prev, f, ln = card.data[-1]
            card.data[-1] = (prev.rstrip() + " " + text, f, ln)
        else:
            card.data.append((text, path, lineno))


def _ints(card: Card, k: int) -> list[int]:
    out = []
    for f in card.fields(k):
        if f:
            try:
                out.append(int(f))
            except ValueError:
                raise DeckError(f"{card.where(k)}: {card.keyword}: expected integers, got {f!r}") from None
    return out


def _floats(card: Card, k: int, n: int | None = None) -> list[float]:
    out = []
    for f in card.fields(k)[:n]:
        if f:
            try:
                out.append(float(f.replace("d", "e").replace("D", "e")))
            except ValueError:
                raise DeckError(f"{card.where(k)}: {card.keyword}: expected a number, got {f!r}") from None
    return out


class Deck:
    """The cards of a deck and the model data read from them.

    Attributes
    ----------
    path : Path
        The main file. ``cards``: every card (includes followed), ``nodes``: id -> (x, y, z),
        ``elements``: id -> (type, node ids), ``nsets`` / ``elsets``: upper-case name -> ids (in order),
        ``materials``: upper-case name -> index of its ``*MATERIAL`` card, ``material_cards``: upper-case
        name -> {keyword: card index} of the cards that follow it, ``sections``: indices of section cards,
        ``first_step``: index of the first ``*STEP`` card (``len(cards)`` without steps).
    """

    def __init__(self, path: Path, cards: list[Card]):
        self.path, self.cards = path, cards
        self.nodes: dict[int, tuple] = {}
        self.elements: dict[int, tuple] = {}
        self.nsets: dict[str, list[int]] = {}
        self.elsets: dict[str, list[int]] = {}
        self.materials: dict[str, int] = {}
        self.material_cards: dict[str, dict[str, int]] = {}
        self.sections: list[int] = []
        self.first_step = len(cards)
        current = None
        for i, c in enumerate(cards):
            if c.keyword == "*STEP":
                self.first_step = min(self.first_step, i)
            if c.keyword == "*NODE" and i < self.first_step:
                ids = []
                for k in range(len(c.data)):
                    v = _floats(c, k)
                    if len(v) < 2:
                        raise DeckError(f"{c.where(k)}: *NODE: expected 'id, x, y[, z]'")
                    ids.append(int(v[0]))
                    self.nodes[int(v[0])] = tuple(v[1:4]) + (0.0,) * (4 - len(v))
                self._add_set(self.nsets, c.param("NSET"), ids)
            elif c.keyword == "*ELEMENT":
                etype = (c.param("TYPE") or "").upper()
                ids = []
                for k in range(len(c.data)):
                    v = _ints(c, k)
                    ids.append(v[0])
                    self.elements[v[0]] = (etype, tuple(v[1:]))
                self._add_set(self.elsets, c.param("ELSET"), ids)
            elif c.keyword in ("*NSET", "*ELSET"):
                sets = self.nsets if c.keyword == "*NSET" else self.elsets
                name = c.param(c.keyword[1:])
                if not name:
                    raise DeckError(f"{c.where()}: {c.keyword} needs {c.keyword[1:]}=<name>")
                self._add_set(sets, name, self._set_members(c, sets))
            if c.keyword == "*MATERIAL":
                name = (c.param("NAME") or "").upper()
                if not name:
                    raise DeckError(f"{c.where()}: *MATERIAL needs NAME=<name>")
                self.materials[name] = i
                self.material_cards[name] = {}
                current = name
            elif current is not None and c.keyword in ("*ELASTIC", "*DENSITY", "*EXPANSION", "*CONDUCTIVITY",
                                                       "*SPECIFIC HEAT", "*PLASTIC", "*DAMPING"):
                self.material_cards[current][c.keyword] = i
            else:
                current = None
            if c.keyword in SECTION_KEYWORDS:
                self.sections.append(i)

    @staticmethod
    def _add_set(sets: dict, name: str | None, ids: list[int]) -> None:
        if name:
            sets.setdefault(name.upper(), []).extend(ids)

    @staticmethod
    def _set_members(c: Card, sets: dict) -> list[int]:
        out = []
        generate = "GENERATE" in c.params
        for k in range(len(c.data)):
            if generate:
                v = _ints(c, k)
                if len(v) not in (2, 3):
                    raise DeckError(f"{c.where(k)}: {c.keyword}, GENERATE: expected 'first, last[, step]'")
                out.extend(range(v[0], v[1] + 1, v[2] if len(v) == 3 else 1))
                continue
            for f in c.fields(k):
                if not f:
                    continue
                if f.lstrip("-").isdigit():
                    out.append(int(f))
                elif f.upper() in sets:
                    out.extend(sets[f.upper()])
                else:
                    raise DeckError(f"{c.where(k)}: {c.keyword}: {f!r} is neither an id nor a defined set")
        return out

    # -- what the updating asks of a deck ---------------------------------------------------------
    def section_of(self, elset: str) -> int:
        """Index of the section card whose ``ELSET`` is ``elset``."""
        hits = [i for i in self.sections if (self.cards[i].param("ELSET") or "").upper() == elset.upper()]
        if not hits:
            raise DeckError(f"{self.path}: no section card (*SOLID/*SHELL/*BEAM SECTION) has ELSET={elset}")
        if len(hits) > 1:
            raise DeckError(f"{self.cards[hits[1]].where()}: a second section card for ELSET={elset}")
        return hits[0]

    def material_number(self, section: int, keyword: str) -> NumberRef:
        """The first number of the section's material's ``*ELASTIC`` (Young's modulus) or ``*DENSITY``."""
        sec = self.cards[section]
        name = (sec.param("MATERIAL") or "").upper()
        if name not in self.materials:
            raise DeckError(f"{sec.where()}: {sec.keyword} names material {name or '(none)'!r}, which the deck "
                            "does not define")
        at = self.material_cards[name].get(keyword)
        if at is None:
            raise DeckError(f"{self.cards[self.materials[name]].where()}: material {name} has no {keyword} card "
                            f"(needed for the segment ELSET={sec.param('ELSET')})")
        card = self.cards[at]
        if keyword == "*ELASTIC" and (card.param("TYPE") or "ISO").upper()[:3] != "ISO":
            raise DeckError(f"{card.where()}: *ELASTIC, TYPE={card.param('TYPE')}: only isotropic moduli are "
                            "factors of a segment")
        if len(card.data) != 1:
            raise DeckError(f"{card.where()}: {keyword} with {len(card.data)} data lines (temperature "
                            "dependent?): a segment factor needs one value")
        return NumberRef(at, 0, 0)

    def number(self, ref: NumberRef) -> float:
        card = self.cards[ref.card]
        if ref.row >= len(card.data):
            raise DeckError(f"{card.where()}: {card.keyword} has no data line {ref.row + 1}")
        values = card.fields(ref.row)
        if ref.field >= len(values) or not values[ref.field]:
            raise DeckError(f"{card.where(ref.row)}: {card.keyword} has no field {ref.field + 1}")
        try:
            return float(values[ref.field].replace("d", "e").replace("D", "e"))
        except ValueError:
            raise DeckError(f"{card.where(ref.row)}: {card.keyword}: field {ref.field + 1} is {values[ref.field]!r}, "
                            "not a number") from None

    def element_nodes(self, elset: str) -> set[int]:
        return {n for e in self.elsets.get(elset.upper(), []) for n in self.elements.get(e, ("", ()))[1]}

    # -- writing ----------------------------------------------------------------------------------
    def text(self, numbers: dict | None = None, params: dict | None = None, extra: str = "",
             steps: str | None = None) -> str:
        """The deck as one text: ``numbers`` {NumberRef: value} and ``params`` {card index: {PARAM: value}}
        replaced, ``extra`` cards added before the steps, and ``steps`` instead of the deck's own (None: keep
        them)."""
        numbers, params = numbers or {}, params or {}
        out = []
        end = self.first_step if steps is not None else len(self.cards)
        for i, c in enumerate(self.cards[:end]):
            if i == self.first_step and extra:
                out.append(extra.rstrip("\n"))
            p = dict(c.params)
            p.update(params.get(i, {}))
            out.append(", ".join([c.keyword] + [k if v == "" else f"{k}={v}" for k, v in p.items()]))
            for k, (line, _, _) in enumerate(c.data):
                fields = line.split(",")
                for ref, value in numbers.items():
                    if ref.card == i and ref.row == k:
                        fields[ref.field] = f" {value!r}" if ref.field else repr(value)
                out.append(",".join(fields))
        if steps is not None or self.first_step == len(self.cards):
            if extra:
                out.append(extra.rstrip("\n"))
            if steps:
                out.append(steps.rstrip("\n"))
        return "\n".join(out) + "\n"


def read_deck(path: str | Path, allowed: list | None = None) -> Deck:
    """Read a deck and the files it includes (only from ``allowed`` folders; default: the deck's folder)."""
    path = Path(path)
    if not path.exists():
        raise DeckError(f"{path}: no such deck")
    folders = [path.parent] + [Path(a) for a in (allowed or [])]
    cards: list[Card] = []
    _read_cards(path, folders, cards, (path.resolve(),))
    return Deck(path, cards)
