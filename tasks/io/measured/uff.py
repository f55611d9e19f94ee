"""Universal File Format dataset 58 (``.uff``, ``.unv``): FRFs and coherence, through pyuff.

What is read from each dataset 58 (record numbers of the standard, pyuff's keys):

- record 6: function type (``func_type``: 4 = FRF, 6 = ordinary coherence;
  others are skipped), load case (``load_case_id``), response node and
  direction (``rsp_node``, ``rsp_dir``: +-1/2/3 = +-X/Y/Z translation, 4-6
  rotations, 0 scalar), reference node and direction (``ref_node``,
  ``ref_dir``);
- record 7: ordinate data type (real or complex, single or double), even or
  uneven abscissa;
- record 9: the ordinate's specific data type (``ordinate_spec_data_type``:
  8 displacement, 11 velocity, 12 acceleration), so the FRF is a receptance,
  mobility or accelerance; record 10: the denominator (13 excitation force,
  9 reaction force, 0 unknown are accepted as force);
- record 12: abscissa (Hz) and ordinates;
- records 1-5 (ID lines, free text): the number of averages when one says ``10 averages``,
  ``averages = 10``, ``Avg: 10`` or ``NAVG 10`` (UFF58 has no field for it; the FRF's lines first, then its
  coherence's); written as ``N averages`` in ID line 2.

Datasets of function type 1 (time response) are raw records: a file with time records and no FRF is
read by :mod:`.time_records` (H1 FRFs and coherence from the hits).

Units (:mod:`.units`): the units labels of records 8-10 and the unit system of the last dataset 164
before the dataset; values are converted to SI and the conversion noted. An unknown label, or one that
contradicts the data type, is refused naming the dataset and the label.

Two forms:

- **with reference nodes** (a real test): channel = (response ``NODE:DIR``,
  reference ``NODE:DIR``), matched to the model's sensors and excitations by
  their ``test_node`` keys when the data meet a model. Several references
  (MIMO) may share a file. A coherence dataset belongs to the FRF with the
  same response and reference node and direction and must share its lines.
- **without a reference node** (``ref_node = 0``, the form this project
  wrote before reference nodes existed): response node = model sensor
  number, direction +Z, the model's default excitation (a combined load has
  no single reference node). The two forms do not mix in one file.

Places: ``dataset k`` counts every dataset in the file from 1, ``point j`` the
abscissa values in it from 1.
"""

from __future__ import annotations

import logging
import re

import numpy as np

from .problems import Problems
from .text import open_uff
from .units import SI_FRF_UNIT, UnitError, frequency_unit, uff_units
from .frf import (DIRECTION_NAMES, MeasuredDataError, MeasuredFRF, dof_label, from_receptance,
                  grid_from_rows, parse_dof)

__all__ = ["read", "write", "UFF_FREQUENCY_RTOL", "UFF_ORDINATE_RTOL", "ORDINATE_KIND", "KIND_ORDINATE", "is_even",
           "check_uneven"]

logger = logging.getLogger(__name__)

#: UFF58 record 6 of the legacy form: the combined load has no single reference node, so the
#: reference node is 0 and the load case is 1 (not 0, which would declare a single-point
#: excitation); the response direction is +Z.
UFF_RESPONSE_DIRECTION = 3
UFF_REFERENCE_NODE = 0
UFF_REFERENCE_DIRECTION = 3
UFF_LOAD_CASE = 1
#: Round-trip tolerances of UFF58 ASCII. Uneven abscissae are Fortran E13.5:
#: 6 significant digits, rounding error <= 5e-6 relative. Ordinates are written
#: in double precision (E20.12 in the standard, ``%20.11e`` by pyuff): 12
#: digits, <= 5e-12. Both doubled to cover the decimal-binary conversion.
UFF_FREQUENCY_RTOL = 1e-5
UFF_ORDINATE_RTOL = 1e-11
#: Record 9 specific data type of the ordinate -> FRF kind, and back.
ORDINATE_KIND = {8: "receptance", 11: "mobility", 12: "accelerance"}
KIND_ORDINATE = {kind: code for code, kind in ORDINATE_KIND.items()}
#: Record 10 specific data types accepted as a force denominator (0 unknown, 9 reaction, 13 excitation).
FORCE_DENOMINATORS = (0, 9, 13)
_UNITS_LABEL = {"receptance": "m", "mobility": "m/s", "accelerance": "m/s^2"}


def read(path) -> MeasuredFRF:
    uff, types = open_uff(path)
    frfs, coherences, skipped, system = [], {}, 0, None
    problems = Problems(path)
    for k, set_type in enumerate(types):
        if set_type not in (58, 164):
            continue
        try:
            dataset = uff.read_sets(k)
        except Exception as exc:
            problems.add(f"dataset {k + 1}: unreadable dataset {set_type} ({exc})")
            continue
        if set_type == 164:
            system = dict(dataset, dataset=k + 1)
            continue
        func_type = dataset.get("func_type")
        if func_type == 4:
            frfs.append((k, dataset, system))
        elif func_type == 6:
            key = _key(dataset)
            if key in coherences:
                problems.add(f"datasets {coherences[key][0] + 1} and {k + 1}: two coherences of response "
                             f"{_label(key[:2])}, reference {_label(key[2:])}")
                continue
            coherences[key] = (k, dataset)
        else:
            skipped += 1
            logger.info("%s: dataset %d (function type %s) is neither an FRF nor a coherence, skipped",
                        path, k + 1, func_type)
    if not frfs:
        problems.add("no FRF found (dataset 58 with function type 4)")
        problems.check()
    legacy = [dataset["ref_node"] == 0 for _, dataset, _ in frfs]
    if any(legacy) and not all(legacy):
        k = frfs[legacy.index(not legacy[0])][0]
        problems.add(f"dataset {k + 1}: FRFs with and without a reference node (0) in one file; without one, the "
                     "data are the legacy form (response node = sensor number)")
        problems.check()
    return _rows(path, frfs, coherences, legacy[0], skipped, problems)


def _key(dataset) -> tuple:
    return (int(dataset["rsp_node"]), int(dataset["rsp_dir"]), int(dataset["ref_node"]), int(dataset["ref_dir"]))


def _label(node_dir) -> str:
    node, direction = node_dir
    return dof_label(node, direction) if abs(direction) <= 6 else f"{node}:{direction}"


def _rows(path, frfs, coherences, legacy, skipped, problems):
    parts, ks, where, kinds, units, notes, counts = [], [], [], [], [], [], []
    used = {_key(dataset) for _, dataset, _ in frfs}  # a coherence whose FRF is faulty is not also an orphan
    complex_kind = set()
    for k, dataset, system in frfs:
        with problems.collect():
            key, x, data, coherence, kind, place, unit = _part(path, k, dataset, system, legacy, coherences, used,
                                                               notes, complex_kind)
            parts.append((key, x, data, coherence, kind))
            counts.append(averages_in_id_lines(dataset, coherences[key][1] if key in coherences else None))
            where += [f"{place} point {j + 1}" for j in range(data.size)]
            kinds += [kind] * data.size
            units += [unit["unit"]] * data.size
            ks.append(k)
    if not parts:
        problems.check()
    return _grid(path, coherences, legacy, skipped, problems, parts, ks, where, kinds, units, notes, used, counts)


#: The number of averages in a dataset 58's ID lines (records 1-5): UFF58 has no field for it, and exporters
#: that write it put it there as text: "10 averages", "averages = 10", "Avg: 10", "NAVG 10".
_AVERAGES = re.compile(r"(?:\b(\d+)\s*(?:averages|avgs?|averaged)\b)|(?:\b(?:averages|avgs?|navg|n_avg|number of "
                       r"averages)\s*[=:]?\s*(\d+)\b)", re.IGNORECASE)


def averages_in_id_lines(dataset, coherence_dataset=None) -> int | None:
    """The number of averages an FRF dataset (else its coherence dataset) states in its ID lines, or None."""
    for d in (dataset, coherence_dataset or {}):
        for name in ("id1", "id2", "id3", "id4", "id5"):
            match = _AVERAGES.search(str(d.get(name, "")))
            if match and int(match.group(1) or match.group(2)) >= 1:
                return int(match.group(1) or match.group(2))
    return None


def _part(path, k, dataset, system, legacy, coherences, used, notes, complex_kind):
    """One FRF dataset checked and converted: (key, abscissa Hz, values SI, coherence, kind, place, unit)."""
    key = _key(dataset)
    if legacy:
        place = f"dataset {k + 1} (sensor {key[0]})"
        if key[1] != UFF_RESPONSE_DIRECTION:
            raise MeasuredDataError(f"{path}: {place}: response direction {key[1]}, expected +Z (3) in a "
                                    "file without reference nodes (the legacy form)")
    else:
        place = f"dataset {k + 1} (response {_label(key[:2])}, reference {_label(key[2:])})"
        for what, direction in (("response", key[1]), ("reference", key[3])):
            if abs(direction) > 6:
                raise MeasuredDataError(f"{path}: {place}: {what} direction {direction} is not a UFF58 "
                                        "direction code (0, +-1 .. +-6)")
    ordinate = int(dataset.get("ordinate_spec_data_type", 0))
    if ordinate not in ORDINATE_KIND and ordinate not in (0, 1):
        raise MeasuredDataError(f"{path}: {place}: ordinate specific data type {ordinate} (record 9); an FRF "
                                "needs 8 (displacement), 11 (velocity) or 12 (acceleration) over force")
    denominator = int(dataset.get("orddenom_spec_data_type", 0))
    if denominator not in FORCE_DENOMINATORS:
        raise MeasuredDataError(f"{path}: {place}: ordinate denominator type {denominator} (record 10) is "
                                "not a force (13, 9 or 0)")
    unit = _units(path, place, dataset, system, ordinate, legacy, k, notes)
    kind = unit["kind"]
    data = np.asarray(dataset["data"])
    if unit["factor"] != 1.0:
        data = data * unit["factor"]
    complex_kind.add(np.iscomplexobj(data))
    if len(complex_kind) > 1:
        raise MeasuredDataError(f"{path}: {place}: real and complex FRFs mixed in one file")
    x = _abscissa(path, place, dataset) * unit["frequency_factor"]
    coherence = None
    if key in coherences:
        used.add(key)
        ck, cset = coherences[key]
        try:
            cx = np.asarray(cset["x"], dtype=float) * frequency_unit(cset.get("abscissa_axis_units_lab", ""))
        except UnitError as exc:
            raise MeasuredDataError(f"{path}: dataset {ck + 1}: record 8: {exc}") from None
        cdata = np.asarray(cset["data"])
        if np.iscomplexobj(cdata) or cx.shape != x.shape or np.any(np.abs(cx - x) > 1e-9 * np.abs(x).max()):
            raise MeasuredDataError(f"{path}: dataset {ck + 1}: the coherence of {place} must be real and "
                                    "have the FRF's frequency lines")
        coherence = cdata.astype(float)
        bad = np.flatnonzero(~((coherence >= 0) & (coherence <= 1)))
        if bad.size:  # named here, in the coherence's own dataset (the grid would name the FRF's)
            more = f" ({bad.size - 1} more points like it)" if bad.size > 1 else ""
            raise MeasuredDataError(f"{path}: dataset {ck + 1} (coherence of {place.split(' (', 1)[1][:-1]}) point "
                                    f"{bad[0] + 1}: coherence {coherence[bad[0]].item()!r} is outside [0, 1]{more}")
    return key, x, data, coherence, kind, place, unit


def _grid(path, coherences, legacy, skipped, problems, parts, ks, where, kinds, units, notes, used, counts):
    """The datasets read as long rows, checked together (:func:`.frf.grid_from_rows`) with every problem so far."""
    given = [c is not None for *_, c, _ in parts]
    if any(given) and not all(given):
        k = ks[given.index(False)]
        problems.add(f"dataset {k + 1}: no coherence dataset for this FRF, while {sum(given)} other FRFs have "
                     "one; give all or none")
    for key in sorted(set(coherences) - used):
        ck = coherences[key][0]
        problems.add(f"dataset {ck + 1}: coherence of response {_label(key[:2])}, reference {_label(key[2:])} "
                     "belongs to no FRF in the file")
    if skipped:
        notes.append(f"skipped {skipped} dataset(s) that are neither FRFs nor coherences")
    frequency = np.concatenate([x for _, x, *_ in parts])
    data = np.concatenate([d for _, _, d, *_ in parts])
    columns = {"frequency_hz": frequency}
    if legacy:
        columns["sensor"] = np.concatenate([np.full(x.size, key[0], dtype=float) for key, x, *_ in parts])
    else:
        columns["response"] = np.concatenate([np.full(x.size, _label(key[:2]), dtype=object)
                                              for key, x, *_ in parts])
        columns["reference"] = np.concatenate([np.full(x.size, _label(key[2:]), dtype=object)
                                               for key, x, *_ in parts])
    if all(given):
        columns["coherence"] = np.concatenate([c for *_, c, _ in parts])
    if all(n is not None for n in counts):
        columns["averages"] = np.concatenate([np.full(x.size, n, dtype=float) for (_, x, *_), n in zip(parts, counts)])
        notes.append(f"number of averages from the datasets' ID lines: {', '.join(map(str, sorted(set(counts))))}")
    elif any(n is not None for n in counts):
        notes.append(f"{sum(n is not None for n in counts)} of {len(counts)} FRF datasets state a number of averages "
                     "in their ID lines, the others none: not used (give --averages)")
    complex_data = None
    if np.iscomplexobj(data):
        complex_data = data
        columns.update(real=data.real.copy(), imag=data.imag.copy())
    else:
        columns["amplitude"] = data.astype(float)
    return grid_from_rows(columns, where, str(path), kinds=np.array(kinds, dtype=object),
                          complex_data=complex_data, file_notes=_unit_notes(notes), units=np.array(units, dtype=object),
                          problems=problems)


def _units(path, place, dataset, system, ordinate, legacy, k, notes) -> dict:
    """The dataset's units (:func:`.units.uff_units`); the legacy form's unlabelled type 0 is receptance in m/N."""
    if legacy and ordinate == 0 and str(dataset.get("ordinate_axis_units_lab", "")).strip().upper() in ("", "NONE"):
        notes.append(f"dataset {k + 1}: ordinate type unknown (0), read as receptance (legacy form)")
        ordinate = KIND_ORDINATE["receptance"]
    try:
        unit = uff_units(dataset, system, ordinate)
    except UnitError as exc:
        raise MeasuredDataError(f"{path}: {place}: {exc}") from None
    source = unit["source"] if system is None or unit["source"] != "dataset 164" else \
        f"unit system of the dataset 164 at dataset {system['dataset']}"
    notes.append(("unit", unit["unit"], unit["kind"], unit["factor"], unit["frequency_factor"], source, k + 1))
    return unit


def _unit_notes(notes) -> list:
    """Plain notes, plus one sentence per distinct unit: how many datasets, the factor to SI, from where."""
    out = [n for n in notes if isinstance(n, str)]
    groups = {}
    for _, unit, kind, factor, ffactor, source, k in (n for n in notes if not isinstance(n, str)):
        groups.setdefault((unit, kind, factor, ffactor, source), []).append(k)
    for (unit, kind, factor, ffactor, source), ks in groups.items():
        si = SI_FRF_UNIT[kind]
        what = "SI, no conversion" if factor == 1.0 else f"converted to {si} (x {factor:.10g})"
        freq = "" if ffactor == 1.0 else f"; abscissa converted to Hz (x {ffactor:.10g})"
        out.append(f"unit {unit} ({kind}) in {len(ks)} dataset(s) ({_ranges(ks)}; {source}): {what}{freq}")
    return out


def _ranges(ks) -> str:
    return "dataset " + ", ".join(str(k) for k in ks[:6]) + (f" ... {ks[-1]}" if len(ks) > 6 else "")


def _abscissa(path, place, dataset) -> np.ndarray:
    x = np.asarray(dataset["x"], dtype=float)
    # A dataset 58 abscissa runs upwards; one that does not is a damaged or mis-exported file.
    back = np.flatnonzero(~(np.diff(x) > 0))
    if back.size:
        j = back[0] + 1
        raise MeasuredDataError(
            f"{path}: {place} point {j + 1}: frequency {x[j]!r} Hz is not above the previous"
            f" point's {x[j - 1]!r} Hz (frequencies out of order)"
        )
    return x


# -- writing -----------------------------------------------------------------------------------
def check_uneven(frequencies, path) -> None:
    """Uneven abscissae keep 6 digits: refuse fewer than two lines or two equal at 6 digits; warn on change."""
    f = np.asarray(frequencies, float)
    stored = np.array([float(f"{v:13.5e}") for v in f])  # as pyuff writes them
    if f.size < 2 or np.unique(stored).size != f.size:
        raise ValueError(f"{path}: UFF58 needs two or more frequencies distinct at 6 digits")
    change = np.max(np.abs(stored - f) / f)
    if change > 0:
        logger.warning("%s: UFF58 keeps 6 digits of frequency, changed by %.1e", path, change)


def is_even(frequencies) -> bool:
    """Evenly spaced lines whose start and step survive E13.5 (then pyuff's x0 + k dx gives them back)."""
    f = np.asarray(frequencies, float)
    if f.size < 2:
        return False
    x0, dx = float(f"{f[0]:13.5e}"), float(f"{f[1] - f[0]:13.5e}")
    return bool(np.all(np.abs(x0 + dx * np.arange(f.size) - f) <= 1e-12 * np.abs(f).max()))


def write(path, measured: MeasuredFRF, kind: str | None = None, even: bool = False) -> None:
    """Write one ASCII dataset 58 per channel (plus one coherence dataset per channel when measured).

    The legacy form (no labels) is written as before: response node = sensor,
    +Z, reference node 0 with load case ``UFF_LOAD_CASE``, uneven abscissa,
    ordinate type 8 (displacement) over 13 (force). Labelled channels need
    ``NODE:DIR`` labels for the response and the reference (names have no
    place in UFF58): load case 0 (single point excitation), ordinate type of
    the channel's kind (or ``kind``), even abscissa when ``even`` and the
    lines are evenly spaced.
    """
    import pyuff

    f = measured.frequencies_hz
    n = measured.n_channels
    kinds = [kind] * n if kind else list(measured.kinds or ["receptance"] * n)
    spacing = 1 if even and is_even(f) else 0
    datasets = []
    for j in range(n):
        values = measured.amplitude[:, j] if measured.complex_frf is None else measured.complex_frf[:, j]
        values = from_receptance(values, f, kinds[j])
        if measured.legacy:
            record6 = dict(load_case_id=UFF_LOAD_CASE, rsp_node=int(measured.sensors[j]),
                           rsp_dir=UFF_RESPONSE_DIRECTION, ref_node=UFF_REFERENCE_NODE,
                           ref_dir=UFF_REFERENCE_DIRECTION)
        else:
            record6 = dict(load_case_id=0, **_node_dir("rsp", measured.responses[j], path),
                           **_node_dir("ref", measured.references[j], path))
        units = "m/N" if measured.legacy and kinds[j] == "receptance" else _UNITS_LABEL[kinds[j]]
        id2 = "NONE" if measured.averages is None else f"{int(measured.averages[j])} averages"
        datasets.append(pyuff.prepare_58(
            binary=0, id1="measured FRF", id2=id2, func_type=4, **record6,
            abscissa_spacing=spacing, abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
            ordinate_spec_data_type=KIND_ORDINATE[kinds[j]], orddenom_spec_data_type=13,
            ordinate_axis_units_lab=units, orddenom_axis_units_lab="N", data=values.copy(), x=f.copy(),
        ))
        if measured.coherence is not None:
            datasets.append(pyuff.prepare_58(
                binary=0, id1="coherence", id2=id2, func_type=6, **record6, abscissa_spacing=spacing,
                abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz", ordinate_spec_data_type=0,
                orddenom_spec_data_type=0, data=measured.coherence[:, j].copy(), x=f.copy(),
            ))
    # force_double: types 4/6 (12 digits); single precision 2/5 keeps only 6.
    pyuff.UFF(str(path)).write_sets(datasets, mode="overwrite", force_double=True)


def _node_dir(prefix: str, label, path) -> dict:
    dof = parse_dof(label) if isinstance(label, str) else None
    if dof is None:
        what = "response" if prefix == "rsp" else "reference"
        raise ValueError(f"{path}: UFF58 needs the {what} as NODE:DIR (a test node), got {label!r}; "
                         f"UFF58 has no names (directions {', '.join(DIRECTION_NAMES.values())})")
    return {f"{prefix}_node": dof[0], f"{prefix}_dir": dof[1]}

