"""Long tables of measured FRFs: CSV and Parquet, one row per channel and frequency line.

Columns (any order; ``response`` or the legacy ``sensor``)::

    response,reference,frequency_hz,real,imag,coherence
    s1,hammer,0.25,1.2e-07,-3.1e-09,0.41
    3:+z,1:+z,0.25,...

=================  ============  ================================================================
column             unit          meaning
=================  ============  ================================================================
``sensor``         -             legacy form: 1-based model sensor, the model's default excitation
``response``       -             a sensor name of the model file, or ``NODE:DIR`` (a test node, e.g.
                                 ``101:+z``, matched through the model's ``test_node`` keys)
``reference``      -             optional: an excitation name or ``NODE:DIR``; empty or absent =
                                 the model's default excitation (its ``excitation`` key)
``frequency_hz``   Hz            > 0; 0 is allowed (and dropped) for mobility and accelerance
``amplitude``      kind's unit   modulus of the FRF, > 0
``real``, ``imag`` kind's unit   the complex FRF (both or neither); with ``amplitude`` the two must
                                 agree to ``AMPLITUDE_RTOL``; either ``amplitude`` or both
``coherence``      -             optional, ordinary coherence in [0, 1]
``kind``           -             optional, per row: receptance (m/N), mobility ((m/s)/N) or
                                 accelerance ((m/s^2)/N), or those units
``averages``       -             optional: the number of averages (hits) behind the channel's FRF
                                 and coherence, one whole number per channel
=================  ============  ================================================================

The number of averages of a whole file: a comment line ``# averages = 10`` (CSV) or the Parquet schema
metadata key ``averages``; an ``averages`` column wins over it.

``unit``: optional, per row: the unit of the row's values, response over force (``g/N``, ``mm/s/N``,
``m/s^2/lbf``; :mod:`.units`); it fixes the row's kind, and the values are converted to SI. The unit of a
whole file: a comment line ``# unit = g/N`` before the first data row (CSV) or the Parquet schema metadata
key ``unit``; a ``unit`` cell overrides it. Without a unit the values are SI in the kind's unit. An
unknown unit, or one of another kind than the row's declared kind, is refused naming it.

The kind of a whole file: a comment line ``# kind = accelerance`` before the
first data row (CSV; other ``#`` lines are comments), or the Parquet schema
metadata key ``kind``. Without either the data are receptance. One file holds
one declared kind: several kinds need the ``kind`` column; a second, different
declaration is refused (the mark of two exports pasted together).

Places: CSV ``line k`` counts every line of the file (header and comments
included) from 1; Parquet ``row k`` counts data rows from 1.
"""

from __future__ import annotations

import csv
import re

import numpy as np

from .frf import KINDS, MeasuredDataError, MeasuredFRF, from_receptance, grid_from_rows, kind_of
from .problems import Problems
from .text import csv_lines
from .units import SI_FRF_UNIT, UnitError, frf_unit

__all__ = ["read_csv", "read_parquet", "write_csv", "write_parquet", "table_columns", "LEGACY_COLUMNS", "COLUMNS"]

LEGACY_COLUMNS = ("sensor", "frequency_hz", "amplitude", "real", "imag")
COLUMNS = LEGACY_COLUMNS + ("response", "reference", "coherence", "kind", "unit", "averages")
TEXT_COLUMNS = ("response", "reference", "kind", "unit")
_DECLARATION = re.compile(r"^#\s*kind\s*[=:]\s*(.*?)\s*$", re.IGNORECASE)
_UNIT_DECLARATION = re.compile(r"^#\s*units?\s*[=:]\s*(.*?)\s*$", re.IGNORECASE)
_AVERAGES_DECLARATION = re.compile(r"^#\s*averages\s*[=:]\s*(.*?)\s*$", re.IGNORECASE)


def _check_header(names, source):
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise MeasuredDataError(f"{source}: column {duplicated[0]!r} appears more than once")
    unknown = [name for name in names if name not in COLUMNS]
    if unknown:
        raise MeasuredDataError(
            f"{source}: unknown column(s) {', '.join(map(repr, unknown))};"
            f" allowed columns: {', '.join(COLUMNS)}"
        )
    if ("sensor" in names) == ("response" in names):
        what = "both" if "sensor" in names else "neither"
        raise MeasuredDataError(f"{source}: {what} of the columns 'sensor' (legacy: model sensor number) and "
                                "'response' (sensor name or NODE:DIR): give exactly one")
    missing = [name for name in ("frequency_hz",) if name not in names]
    if "amplitude" not in names and not {"real", "imag"} & set(names):
        missing.append("amplitude")
    if missing:
        listed = ", ".join(map(repr, missing))
        raise MeasuredDataError(f"{source}: missing required column(s) {listed}"
                                + (" (or 'real' and 'imag')" if "amplitude" in missing else ""))
    if ("real" in names) != ("imag" in names):
        raise MeasuredDataError(f"{source}: columns 'real' and 'imag' go together, one is missing")
    if "reference" in names and "sensor" in names:
        raise MeasuredDataError(f"{source}: column 'reference' needs 'response' (the legacy 'sensor' form is "
                                "measured under the model's default excitation)")


def _to_float(cells, name, where, source, problems: Problems, bad: np.ndarray):
    """Parse cells one by one so that each bad one can be named (added to ``problems``, its row marked ``bad``)."""
    values = np.empty(len(cells))
    for i, cell in enumerate(cells):
        if cell is None or (isinstance(cell, str) and not cell.strip()):
            problems.add(f"{where[i]}: {name} is empty")
            values[i], bad[i] = np.nan, True
            continue
        try:
            values[i] = float(cell)
        except (TypeError, ValueError):
            problems.add(f"{where[i]}: {name} {cell!r} is not a number")
            values[i], bad[i] = np.nan, True
    return values


def _to_text(cells, name, where, source, problems: Problems, bad: np.ndarray):
    out = np.empty(len(cells), dtype=object)
    for i, cell in enumerate(cells):
        if cell is None:
            cell = ""
        if not isinstance(cell, str):
            problems.add(f"{where[i]}: {name} {cell!r} is not text")
            cell, bad[i] = "", True
        out[i] = cell.strip()
    return out


def _kinds(columns, where, source, declared, declared_at):
    """The kind of each row: the ``kind`` column, else the file's declaration, else receptance."""
    r = len(where)
    if "kind" not in columns:
        return np.full(r, declared or "receptance", dtype=object)
    kinds = np.empty(r, dtype=object)
    for i, cell in enumerate(columns.pop("kind")):
        kind = kind_of(cell) if cell else (declared or "receptance")
        if kind is None:
            raise MeasuredDataError(f"{source}: {where[i]}: kind {cell!r} is not one of {', '.join(KINDS)} "
                                    "(or m/N, m/s/N, m/s^2/N)")
        if declared and kind != declared:
            raise MeasuredDataError(f"{source}: {where[i]}: kind {kind}, but {declared_at} declares {declared} "
                                    "for the whole file")
        kinds[i] = kind
    return kinds


def _units(columns, where, source, kinds, explicit, unit, unit_at):
    """Scale the values of rows with a unit (``unit`` column, else the file's) to SI; the unit fixes the kind.

    Returns the unit of each row (None without any) and the notes. ``explicit`` marks rows whose kind was
    given (column or declaration): it must be the unit's.
    """
    cells = columns.pop("unit", None)
    if cells is None and unit is None:
        si = ", ".join(SI_FRF_UNIT[k] for k in sorted(set(kinds.tolist())))
        return None, [f"no unit given (no '# unit = ...' line, no 'unit' column): values read as SI ({si})"]
    r = len(where)
    labels = np.array([(c or unit or "") for c in (cells if cells is not None else [""] * r)], dtype=object)
    if np.any(labels == ""):
        i = int(np.flatnonzero(labels == "")[0])
        raise MeasuredDataError(f"{source}: {where[i]}: unit is empty and the file declares none (# unit = g/N); "
                                "give every row a unit or none")
    notes = []
    for label in dict.fromkeys(labels.tolist()):
        rows = np.flatnonzero(labels == label)
        try:
            kind, factor = frf_unit(label)
        except UnitError as exc:
            at = unit_at if cells is None or not cells[rows[0]] else where[rows[0]]
            raise MeasuredDataError(f"{source}: {at}: {exc}") from None
        clash = rows[explicit[rows] & (kinds[rows] != kind)]
        if clash.size:
            i = clash[0]
            raise MeasuredDataError(f"{source}: {where[i]}: unit {label!r} is a {kind}, but the row's kind is "
                                    f"{kinds[i]}")
        kinds[rows] = kind
        for name in ("amplitude", "real", "imag"):
            if name in columns and factor != 1.0:
                columns[name] = np.array(columns[name], dtype=float)
                columns[name][rows] *= factor
        what = "SI, no conversion" if factor == 1.0 else f"converted to {SI_FRF_UNIT[kind]} (x {factor:.10g})"
        origin = f"{unit_at} declares it" if cells is None or not np.all([cells[i] for i in rows]) else "unit column"
        notes.append(f"unit {label} ({kind}) in {rows.size} row(s) ({origin}): {what}")
    return labels, notes


def _rows(names, records, where, source, declared=None, declared_at="", unit=None, unit_at="", problems=None,
          averages=None):
    problems = problems if problems is not None else Problems(source)
    bad = np.zeros(len(where), dtype=bool)
    columns = {}
    for name, cells in zip(names, records):
        reader = _to_text if name in TEXT_COLUMNS else _to_float
        columns[name] = reader(cells, name, where, source, problems, bad)
    return _grid(columns, where, source, declared, declared_at, unit, unit_at, problems, bad, averages)


def _grid(columns, where, source, declared, declared_at, unit, unit_at, problems=None, bad=None, averages=None):
    """Kinds and units of the rows, then :func:`.frf.grid_from_rows`; the problems of every step in one message.

    ``averages``: ``(text, place)`` of the file's ``averages`` declaration, or None.
    """
    problems = problems if problems is not None else Problems(source)
    if averages is not None and "averages" not in columns:
        text, place = averages
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (value >= 1 and value == round(value)):
            raise MeasuredDataError(f"{source}: {place}: averages {text!r} is not a whole number >= 1")
        columns["averages"] = np.full(len(where), value)
    explicit = np.full(len(where), declared is not None)
    if "kind" in columns:
        explicit |= np.array([bool(c) for c in columns["kind"]], dtype=bool)
    before = len(problems)
    with problems.collect():
        kinds = _kinds(columns, where, source, declared, declared_at)
        labels, unit_notes = _units(columns, where, source, kinds, explicit, unit, unit_at)
    if len(problems) > before:
        problems.check()  # a kind or unit unknown: the values cannot be converted, the grid not checked
    notes = [f"{declared_at} declares the file's kind: {declared}"] if declared else []
    return grid_from_rows(columns, where, str(source), kinds=kinds, file_notes=notes + unit_notes, units=labels,
                          problems=problems, bad_rows=bad)


# -- CSV ---------------------------------------------------------------------------------------
def read_csv(path) -> MeasuredFRF:
    declared, declared_at, unit, unit_at, averages = None, "", None, "", None
    records, where, comments = csv_lines(path)
    for text, place, before in comments:
        match = _DECLARATION.match(text)
        unit_match = _UNIT_DECLARATION.match(text)
        averages_match = _AVERAGES_DECLARATION.match(text)
        if averages_match:
            averages = (averages_match.group(1), place)
        if unit_match:
            if unit is not None or before > 1:
                raise MeasuredDataError(f"{path}: {place}: a second unit declaration or one after data rows; one "
                                        "'# unit = ...' before the header or the first data row, or a 'unit' column")
            unit, unit_at = unit_match.group(1), place
        if match:
            declared, declared_at = _declaration(match.group(1), place, path, declared, declared_at, before > 1)
    if not records:
        raise MeasuredDataError(f"{path}: empty file (no header line)")
    names = [name.strip() for name in records[0]]
    _check_header(names, path)
    problems = Problems(path)
    kept, kept_where = [], []
    for record, place in zip(records[1:], where[1:]):
        if len(record) != len(names):
            problems.add(f"{place}: {len(record)} fields, the header has {len(names)}")
        else:
            kept.append(record)
            kept_where.append(place)
    if not kept:
        problems.check()
    cells = list(zip(*kept)) or [()] * len(names)
    return _rows(names, cells, kept_where, path, declared, declared_at, unit, unit_at, problems, averages)


def _declaration(text, place, path, declared, declared_at, after_data):
    kind = kind_of(text)
    if kind is None:
        raise MeasuredDataError(f"{path}: {place}: kind {text!r} is not one of {', '.join(KINDS)} "
                                "(or m/N, m/s/N, m/s^2/N)")
    if declared is not None and kind != declared:
        raise MeasuredDataError(f"{path}: {place} declares {kind}, {declared_at} declared {declared}: mixed FRF "
                                "kinds in one file need a 'kind' column saying which row is which")
    if declared is None and after_data:
        raise MeasuredDataError(f"{path}: {place} declares {kind} after data rows of no declared kind "
                                "(receptance): mixed FRF kinds in one file need a 'kind' column")
    return kind, declared_at or place


# -- Parquet -----------------------------------------------------------------------------------
def read_parquet(path) -> MeasuredFRF:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise MeasuredDataError(f"{path}: not a Parquet table ({exc})") from None
    names = list(table.column_names)
    _check_header(names, path)
    where = [f"row {i + 1}" for i in range(table.num_rows)]
    metadata = table.schema.metadata or {}
    declared = None
    if b"kind" in metadata:
        text = metadata[b"kind"].decode("utf-8", errors="replace")
        declared = kind_of(text)
        if declared is None:
            raise MeasuredDataError(f"{path}: schema metadata 'kind' = {text!r} is not one of {', '.join(KINDS)}")
    problems, bad = Problems(path), np.zeros(table.num_rows, dtype=bool)
    cells = []
    for name in names:
        values = table.column(name).to_numpy(zero_copy_only=False)
        if name not in TEXT_COLUMNS and values.dtype.kind in "iuf":
            values = values.astype(float)
        cells.append(values)
    columns = {}
    for name, values in zip(names, cells):
        if name in TEXT_COLUMNS:
            columns[name] = _to_text(values, name, where, path, problems, bad)
        elif values.dtype.kind == "f":
            columns[name] = values
        else:
            columns[name] = _to_float(values, name, where, path, problems, bad)
    unit = metadata[b"unit"].decode("utf-8", errors="replace") if b"unit" in metadata else None
    averages = None
    if b"averages" in metadata:
        averages = (metadata[b"averages"].decode("utf-8", errors="replace"), "the schema metadata 'averages'")
    return _grid(columns, where, path, declared, "the schema metadata", unit, "the schema metadata 'unit'", problems,
                 bad, averages)


# -- writing -----------------------------------------------------------------------------------
def table_columns(measured: MeasuredFRF, kind: str | None = None) -> dict:
    """The long table of ``measured``, rows frequency-major, values in each channel's kind.

    ``kind`` writes every channel as that kind instead of the one it was read as.
    The legacy form without coherence or other kinds gives exactly the legacy
    columns ``sensor, frequency_hz, amplitude[, real, imag]``.
    """
    p, n = measured.amplitude.shape
    f = measured.frequencies_hz
    kinds = [kind] * n if kind else list(measured.kinds or ["receptance"] * n)
    amplitude = np.column_stack([from_receptance(measured.amplitude[:, j], f, kinds[j]) for j in range(n)])
    columns = {}
    if measured.legacy:
        columns["sensor"] = np.tile(measured.sensors, p)
    else:
        columns["response"] = np.tile(np.array(measured.responses, dtype=object), p)
        if any(r is not None for r in measured.references):
            refs = np.array(["" if r is None else r for r in measured.references], dtype=object)
            columns["reference"] = np.tile(refs, p)
    columns["frequency_hz"] = np.repeat(f, n)
    columns["amplitude"] = amplitude.ravel()
    if measured.complex_frf is not None:
        frf = np.column_stack([from_receptance(measured.complex_frf[:, j], f, kinds[j]) for j in range(n)])
        columns.update(real=frf.real.ravel(), imag=frf.imag.ravel())
    if measured.coherence is not None:
        columns["coherence"] = measured.coherence.ravel()
    if any(k != "receptance" for k in kinds):
        columns["kind"] = np.tile(np.array(kinds, dtype=object), p)
    if measured.averages is not None:
        columns["averages"] = np.tile(measured.averages, p)
    return columns


def write_csv(path, measured: MeasuredFRF, kind: str | None = None) -> None:
    columns = table_columns(measured, kind)
    with open(path, "x", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        # tolist() gives Python floats, which csv writes with repr: exact round trip.
        writer.writerows(zip(*(values.tolist() for values in columns.values())))


def write_parquet(path, measured: MeasuredFRF, kind: str | None = None) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns = table_columns(measured, kind)
    pq.write_table(pa.table({k: (v.astype(str) if v.dtype == object else v) for k, v in columns.items()}), path)
