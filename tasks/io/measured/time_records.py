"""Raw hammer records: UFF58 time records (function type 1) and tables of samples, read into FRFs.

The records are checked and turned into H1 FRFs with coherence over the hits by :mod:`.records`; the
result is the same :class:`MeasuredFRF` as an FRF file gives (accelerance etc. converted to receptance,
``averages`` = the number of hits).

**UFF58** (``.uff``, ``.unv``): a file whose datasets 58 hold time records (record 6 function type 1) and
no FRF. Per dataset: record 6's response node and direction (the transducer's DOF); record 9's data
type, 13 (excitation force) for the force and 8, 11, 12 (displacement, velocity, acceleration) for a
response, or 0 with a units label that says which (``N``, ``lbf``; ``g``, ``m/s^2``); record 9's units label
(:mod:`.units`; none = SI, noted); record 8's abscissa in seconds (``s``, ``sec`` or none; ``ms``). A *hit*
is the records that share record 6's load case and version (sequence) number. The reference of every
channel is the force record's node and direction.

**Table of samples** (``.csv``, ``.parquet``), one row per sample of a hit::

    # reference = 5:+z
    # response_unit = g
    # force_unit = N
    hit,time,force,1:+z,2:+z,s3
    1,0.0,0.013,0.0021,-0.0007,0.0011
    ...

columns ``time`` (s, evenly spaced, increasing within a hit), ``force``, ``hit`` (optional: one hit without
it) and one column per response channel, named by its label (a sensor name or ``NODE:DIR``). The comment
lines (Parquet: schema metadata keys of the same names) give the reference (the force's ``NODE:DIR`` or an
excitation name; none = the model's default excitation), the response unit (default ``m/s^2``, noted) and
the force unit (default ``N``).

Refused, naming the file and the dataset, line or column: no force record or column, sample rates that
differ between channels or hits, records of different lengths within a hit or between hits, a hit without
a pulse, a double hit, a hit without one of the channels, a value that is not a finite number.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from .frf import MeasuredDataError, dof_label, grid_from_rows, parse_dof
from .problems import Problems
from .records import Records, RecordOptions, h1_from_records
from .text import csv_lines, open_uff
from .units import UnitError, force_unit, numerator_unit

__all__ = ["is_time_records", "read", "write_uff", "write_table", "FORCE_TYPE", "RESPONSE_TYPES"]

#: UFF58 record 9 data type of the force, and of the responses.
FORCE_TYPE = 13
RESPONSE_TYPES = {8: "displacement", 11: "velocity", 12: "acceleration"}
_TIME_UNITS = {"": 1.0, "none": 1.0, "s": 1.0, "sec": 1.0, "seconds": 1.0, "ms": 1e-3}
_SI_RESPONSE = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}
_DECLARATION = re.compile(r"^#\s*(reference|response_unit|force_unit)\s*[=:]\s*(.*?)\s*$", re.IGNORECASE)
#: Relative agreement of two sampling intervals (UFF keeps 6 digits of the abscissa increment).
RATE_RTOL = 1e-5


def is_time_records(path) -> bool:
    """True for raw records: a UFF with time records and no FRF, or a table with a ``time`` column."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix in (".csv",):
            with open(path, newline="", encoding="utf-8-sig") as fh:
                for line in fh:
                    if line.strip() and not line.lstrip().startswith("#"):
                        return "time" in [c.strip() for c in next(csv.reader([line]))]
        elif suffix == ".parquet":
            import pyarrow.parquet as pq

            return "time" in pq.read_schema(path).names
        elif suffix in (".uff", ".unv"):
            import pyuff

            uff = pyuff.UFF(str(path))
            kinds = {uff.read_sets(k, header_only=True).get("func_type")
                     for k, t in enumerate(uff.get_set_types()) if t == 58}
            return 1 in kinds and 4 not in kinds
    except Exception:  # unreadable: the format's own reader says why
        return False
    return False


def read(path, options: RecordOptions | None = None):
    """Raw records -> :class:`MeasuredFRF` (H1, coherence, averages = hits); see the module docstring."""
    path = Path(path)
    records = _read_uff(path) if path.suffix.lower() in (".uff", ".unv") else _read_table(path)
    result = h1_from_records(records, options)
    f, frf, n = result["frequency_hz"], result["frf"], records.responses.shape[1]
    p = f.size
    columns = {
        "response": np.repeat(np.array(records.labels, dtype=object), p),
        "reference": np.full(p * n, records.reference or "", dtype=object),
        "frequency_hz": np.tile(f, n),
        "coherence": result["coherence"].T.ravel(),
        "averages": np.full(p * n, float(result["averages"])),
    }
    data = frf.T.ravel()
    columns.update(real=data.real.copy(), imag=data.imag.copy())
    where = [f"channel {records.labels[c]} at {f[i]:g} Hz" for c in range(n) for i in range(p)]
    return grid_from_rows(columns, where, str(path), kinds=np.repeat(np.array(result["kinds"], dtype=object), p),
                          complex_data=data, file_notes=records.notes + result["notes"],
                          units=np.repeat(np.array(records.units, dtype=object), p))


def _rate(dt, place, problems):
    """Sample rate from a sampling interval; within UFF's 6 digits of a whole number of Hz it is that number."""
    if not (np.isfinite(dt) and dt > 0):
        problems.add(f"{place}: sampling interval {dt!r} s is not > 0")
        return None
    fs = 1.0 / dt
    return float(round(fs)) if abs(fs - round(fs)) <= RATE_RTOL * fs else fs


def _check_rates(items, problems, what):
    """``items``: (place, sample rate, samples) of every record; one rate and one length (per hit)."""
    items = [i for i in items if i[1] is not None]
    if not items:
        return None
    place0, fs0, _ = items[0]
    for place, fs, _ in items[1:]:
        if abs(fs - fs0) > RATE_RTOL * fs0:
            problems.add(f"{place}: sample rate {fs:.8g} Hz, but {place0} has {fs0:.8g} Hz: mismatched sample rates")
            break
    return fs0


def _check_lengths(groups, problems):
    """``groups``: {hit: [(place, samples), ...]}: one length within each hit and over the hits."""
    first = None
    for hit, items in groups.items():
        (p0, n0) = items[0]
        for place, n in items[1:]:
            if n != n0:
                problems.add(f"{place}: {n} samples, but {p0} of the same hit has {n0}: records of different "
                             "lengths within a hit")
                break
        if first is None:
            first = (p0, n0)
        elif n0 != first[1]:
            problems.add(f"{p0}: {n0} samples, but {first[0]} has {first[1]}: hits of different lengths")


# -- UFF58 -------------------------------------------------------------------------------------
def _read_uff(path) -> Records:
    uff, types = open_uff(path)
    problems, hits, notes, unlabelled = Problems(path), {}, [], []
    for k, set_type in enumerate(types):
        if set_type != 58:
            continue
        try:
            d = uff.read_sets(k)
        except Exception as exc:
            problems.add(f"dataset {k + 1}: unreadable dataset 58 ({exc})")
            continue
        if d.get("func_type") != 1:
            continue
        with problems.collect():
            hits.setdefault((int(d.get("load_case_id", 0)), int(d.get("ver_num", 0))), []).append(
                _uff_record(path, k, d, unlabelled))
    if not hits:
        problems.add("no time record (dataset 58 with function type 1)")
    problems.check()
    if unlabelled:
        notes.append(f"no units label in {len(unlabelled)} time record(s) (dataset {unlabelled[0]}, ...): read as SI")
    return _assemble(path, hits, notes, problems, lambda key: f"load case {key[0]}, sequence number {key[1]}")


def _uff_record(path, k, d, unlabelled) -> dict:
    place = f"dataset {k + 1}"
    data = np.asarray(d["data"])
    if np.iscomplexobj(data):
        raise MeasuredDataError(f"{path}: {place}: a time record must be real, the dataset holds complex values")
    x = np.asarray(d["x"], dtype=float)
    time_label = str(d.get("abscissa_axis_units_lab", "")).strip().lower()
    if time_label not in _TIME_UNITS or int(d.get("abscissa_spec_data_type", 17) or 17) not in (0, 17):
        raise MeasuredDataError(f"{path}: {place}: record 8: abscissa {d.get('abscissa_spec_data_type')} "
                                f"{time_label!r} is not a time (data type 17, s or ms)")
    x = x * _TIME_UNITS[time_label]
    if x.size < 2 or np.any(np.abs(np.diff(x) - (x[1] - x[0])) > 1e-4 * abs(x[1] - x[0])):
        raise MeasuredDataError(f"{path}: {place}: the time abscissa is not evenly spaced (or has < 2 samples)")
    ordinate = int(d.get("ordinate_spec_data_type", 0) or 0)
    label = str(d.get("ordinate_axis_units_lab", "")).strip()
    if label.upper() == "NONE":
        label = ""
    dof = dof_label(int(d["rsp_node"]), int(d["rsp_dir"])) if abs(int(d["rsp_dir"])) <= 6 else None
    if dof is None:
        raise MeasuredDataError(f"{path}: {place}: response direction {d['rsp_dir']} is not a UFF58 direction code")
    is_force = ordinate == FORCE_TYPE
    if ordinate == 0 and label:
        try:
            force_unit(label)
            is_force = True
        except UnitError:
            is_force = False
    elif ordinate not in RESPONSE_TYPES and not is_force:
        raise MeasuredDataError(f"{path}: {place}: record 9 data type {ordinate} is neither the force "
                                f"({FORCE_TYPE}) nor a response (8, 11, 12)")
    if not label:
        unlabelled.append(k + 1)
    try:
        if is_force:
            factor, quantity = force_unit(label or "N"), "force"
        else:
            quantity, factor = numerator_unit(label or _SI_RESPONSE[RESPONSE_TYPES[ordinate]])
            if ordinate in RESPONSE_TYPES and quantity != RESPONSE_TYPES[ordinate]:
                raise UnitError(f"units label {label!r} is a {quantity}, but data type {ordinate} is a "
                                f"{RESPONSE_TYPES[ordinate]}")
    except UnitError as exc:
        raise MeasuredDataError(f"{path}: {place}: record 9: {exc}") from None
    return {"place": place, "dof": dof, "force": is_force, "quantity": quantity, "unit": label or "SI",
            "values": data.astype(float) * factor, "dt": x[1] - x[0], "node": int(d["rsp_node"])}


def _assemble(path, hits, notes, problems, name) -> Records:
    """Hits of records -> :class:`Records`: one force per hit, the same channels, rate and length everywhere."""
    forces, channels, rates, lengths = {}, None, [], {}
    for key, items in hits.items():
        hit = name(key)
        force = [r for r in items if r["force"]]
        if not force:
            problems.add(f"{hit} ({', '.join(r['place'] for r in items[:3])}): no force record: a time record "
                         "without a force channel (UFF58: record 9 data type 13 or a force unit; table: 'force')")
            continue
        if len(force) > 1:
            problems.add(f"{force[1]['place']}: a second force record in {hit} ({force[0]['place']} is the first)")
        forces[key] = force[0]
        mine = {}
        for r in items:
            if not r["force"]:
                if r["dof"] in mine:
                    problems.add(f"{r['place']}: a second record of {r['dof']} in {hit}")
                mine[r["dof"]] = r
        if channels is None:
            channels = list(mine)
        elif set(mine) != set(channels):
            missing, extra = sorted(set(channels) - set(mine)), sorted(set(mine) - set(channels))
            problems.add(f"{hit}: channels differ from the first hit's: missing {missing}, unexpected {extra}")
        for r in items:
            rates.append((r["place"], _rate(r["dt"], r["place"], problems), r["values"].size))
        lengths[hit] = [(r["place"], r["values"].size) for r in items]
    fs = _check_rates(rates, problems, "sample rate")
    _check_lengths(lengths, problems)
    if forces and not channels:
        problems.add("no response record (only forces)")
    problems.check()
    refs = {forces[k]["dof"] for k in forces}
    if len(refs) > 1:
        raise MeasuredDataError(f"{path}: the force is at {sorted(refs)} in different hits: one reference per file "
                                "(a roving-hammer test: one file per hit point)")
    keys = list(forces)
    first = hits[keys[0]]
    units = sorted({r["unit"] for items in hits.values() for r in items})
    notes.append(f"record units {', '.join(units)} converted to SI (m/s^2, m/s or m; N)")
    by_dof = {r["dof"]: r for r in first if not r["force"]}
    force0 = forces[keys[0]]
    ref = force0["dof"] if force0.get("node", 1) != 0 else None
    return Records(
        sample_rate_hz=fs,
        force=np.array([forces[k]["values"] for k in keys]),
        responses=np.array([[next(r for r in hits[k] if not r["force"] and r["dof"] == c)["values"]
                             for c in channels] for k in keys]),
        labels=list(channels), quantities=[by_dof[c]["quantity"] for c in channels], reference=ref,
        units=[f"{by_dof[c]['unit']}/{force0['unit']}" for c in channels],
        hits=[f"{forces[k]['place']} ({name(k)})" for k in keys], source=str(path), notes=notes)


# -- tables of samples -------------------------------------------------------------------------
def _read_table(path) -> Records:
    declared, where = {}, []
    if path.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
        except (pa.ArrowException, OSError) as exc:
            raise MeasuredDataError(f"{path}: not a Parquet table ({exc})") from None
        names = list(table.column_names)
        cells = [table.column(n).to_numpy(zero_copy_only=False) for n in names]
        for key, value in (table.schema.metadata or {}).items():
            declared[key.decode("utf-8", "replace")] = (value.decode("utf-8", "replace"), "the schema metadata")
        where = [f"row {i + 1}" for i in range(table.num_rows)]
    else:
        rows, where, comments = csv_lines(path)
        for text, place, _ in comments:
            match = _DECLARATION.match(text)
            if match:
                declared[match.group(1).lower()] = (match.group(2), place)
        if not rows:
            raise MeasuredDataError(f"{path}: empty file (no header line)")
        names = [n.strip() for n in rows[0]]
        problems = Problems(path)
        body = []
        for record, place in zip(rows[1:], where[1:]):
            if len(record) != len(names):
                problems.add(f"{place}: {len(record)} fields, the header has {len(names)}")
            body.append(record if len(record) == len(names) else [""] * len(names))
        problems.check()
        where = where[1:]
        cells = list(zip(*body)) or [()] * len(names)
    return _table_records(path, names, cells, where, declared)


def _table_records(path, names, cells, where, declared) -> Records:
    problems = Problems(path)
    if len(set(names)) != len(names):
        raise MeasuredDataError(f"{path}: a column appears more than once")
    if "force" not in names:
        raise MeasuredDataError(f"{path}: no 'force' column: a time record without a force channel (columns: "
                                f"{', '.join(names)})")
    labels = [n for n in names if n not in ("hit", "time", "force")]
    if not labels:
        raise MeasuredDataError(f"{path}: no response column (one per channel, named by its label)")
    for label in labels:
        try:
            parse_dof(label)
        except ValueError as exc:
            problems.add(f"column {label!r}: {exc}")
    values = {}
    for name, column in zip(names, cells):
        out = np.empty(len(column))
        for i, cell in enumerate(column):
            try:
                out[i] = float(cell)
            except (TypeError, ValueError):
                out[i] = np.nan
            if not np.isfinite(out[i]):
                problems.add(f"{where[i]}: {name} {cell!r} is not a finite number")
        values[name] = out
    problems.check()
    response_label, unit_at = declared.get("response_unit", ("", ""))
    force_label, force_at = declared.get("force_unit", ("N", ""))
    notes = []
    try:
        quantity, factor = numerator_unit(response_label or "m/s^2")
    except UnitError as exc:
        raise MeasuredDataError(f"{path}: {unit_at}: response_unit: {exc}") from None
    try:
        f_factor = force_unit(force_label)
    except UnitError as exc:
        raise MeasuredDataError(f"{path}: {force_at}: force_unit: {exc}") from None
    if not response_label:
        notes.append("no response_unit declared: responses read as accelerations in m/s^2")
    hit = values.get("hit", np.ones(len(where)))
    hits = {}
    for h in dict.fromkeys(hit.tolist()):
        rows = np.flatnonzero(hit == h)
        t = values["time"][rows]
        place = f"hit {h:g} ({where[rows[0]]})"
        step = np.diff(t)
        if t.size < 2 or np.any(step <= 0) or np.any(np.abs(step - step[0]) > 1e-6 * step[0]):
            bad = 1 + int(np.argmax((step <= 0) | (np.abs(step - step[0]) > 1e-6 * step[0]))) if t.size > 1 else 0
            problems.add(f"{where[rows[bad]]}: time {t[bad]!r} s: the samples of hit {h:g} are not evenly spaced "
                         "and increasing")
            continue
        records = [{"place": place, "dof": "force", "force": True, "quantity": "force", "unit": force_label,
                    "values": values["force"][rows] * f_factor, "dt": step[0]}]
        for label in labels:
            records.append({"place": f"{place} column {label!r}", "dof": label, "force": False, "quantity": quantity,
                            "unit": response_label or "m/s^2", "values": values[label][rows] * factor,
                            "dt": step[0]})
        hits[h] = records
    problems.check()
    out = _assemble(path, hits, notes, problems, lambda key: f"hit {key:g}")
    reference = declared.get("reference", ("", ""))[0].strip()
    if reference:
        try:
            dof = parse_dof(reference)
        except ValueError as exc:
            raise MeasuredDataError(f"{path}: {declared['reference'][1]}: reference {exc}") from None
        reference = reference if dof is None else dof_label(*dof)
    out.reference = reference or None
    return out


# -- writing (the generator, tests) ------------------------------------------------------------
def write_uff(path, fs, force, responses, labels, reference, response_unit="m/s^2", force_unit_label="N",
              quantity="acceleration", id_text="hammer records"):
    """Write hits as UFF58 ASCII time records (single precision: 6 digits), one force and ``c`` responses each.

    ``force`` (h, t) and ``responses`` (h, c, t) in the units named; ``labels``: ``NODE:DIR`` per channel;
    ``reference``: the force's ``NODE:DIR``. Hit ``i`` has sequence number ``i + 1``.
    """
    import pyuff

    code = {v: k for k, v in RESPONSE_TYPES.items()}[quantity]
    t = np.arange(force.shape[1]) / fs
    sets = []
    for h in range(force.shape[0]):
        for values, label, ordinate, unit in [(force[h], reference, FORCE_TYPE, force_unit_label)] + [
                (responses[h, c], labels[c], code, response_unit) for c in range(len(labels))]:
            node, direction = parse_dof(label)
            sets.append(dict(ord_data_type=2, **pyuff.prepare_58(
                binary=0, id1=f"{id_text}: hit {h + 1}", id2=f"time record {label}", func_type=1, ver_num=h + 1,
                load_case_id=1, rsp_node=node, rsp_dir=direction, ref_node=0, ref_dir=0, abscissa_spacing=1,
                abscissa_spec_data_type=17, abscissa_axis_units_lab="s", ordinate_spec_data_type=ordinate,
                ordinate_axis_units_lab=unit, orddenom_spec_data_type=0, data=np.asarray(values, float), x=t)))
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=False)


def write_table(path, fs, force, responses, labels, reference=None, response_unit="m/s^2", force_unit_label="N"):
    """Write hits as a table of samples (CSV, or Parquet in float32) with the declarations of the module docstring."""
    h, c, n = responses.shape
    columns = {"hit": np.repeat(np.arange(1, h + 1), n), "time": np.tile(np.arange(n) / fs, h),
               "force": force.ravel()}
    for j, label in enumerate(labels):
        columns[label] = responses[:, j, :].ravel()
    meta = {"response_unit": response_unit, "force_unit": force_unit_label}
    if reference:
        meta["reference"] = reference
    if Path(path).suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        arrays = {k: (v.astype(np.int32) if k == "hit" else v.astype(np.float32 if k != "time" else np.float64))
                  for k, v in columns.items()}
        table = pa.table(arrays).replace_schema_metadata({k: str(v) for k, v in meta.items()})
        pq.write_table(table, path, compression="zstd")
        return
    with open(path, "w", newline="", encoding="utf-8") as fh:
        for key, value in meta.items():
            fh.write(f"# {key} = {value}\n")
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(zip(*(v.tolist() for v in columns.values())))
