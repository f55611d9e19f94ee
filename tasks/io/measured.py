"""Measured frequency-response amplitudes: format, reader, writer and checks.

The measured data are a long table with one row per (sensor, frequency)::

    sensor,frequency_hz,amplitude,real,imag
    1,106.0,3.2e-06,-1.6e-06,2.771281292110204e-06
    2,106.0,1.5e-06,1.2e-06,9e-07
    1,106.5,3.4e-06,...

========================  =======  ===============================================
column                    unit     meaning
========================  =======  ===============================================
``sensor``                -        1-based integer sensor id, >= 1
``frequency_hz``          Hz       excitation frequency, > 0
``amplitude``             m/N      modulus of the receptance FRF, > 0
``real``, ``imag``        m/N      optional complex FRF; both or neither, and then
                                   ``amplitude == hypot(real, imag)`` to a relative
                                   ``AMPLITUDE_RTOL``
========================  =======  ===============================================

Rows may come in any order, but the grid must be complete: every sensor has
exactly one row at every frequency. Frequencies of different sensors match
exactly (same number in the file), not within a tolerance.

Files are ``.csv`` (comma-separated, one header line), ``.parquet``, or
``.uff`` / ``.unv`` (Universal File Format dataset 58, one dataset per sensor,
see ``write_measured``). Every problem raises ``MeasuredDataError`` with the
file and the place: for CSV ``line k`` is the line number in the file (the
header is line 1, so the first data row is line 2); for Parquet ``row k`` is
the 1-based data row; for UFF ``dataset k`` counts every dataset in the file
from 1 and ``point j`` the abscissa values in it from 1.
"""

import argparse
import csv
import io
import logging
import os
import sys
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

REQUIRED_COLUMNS = ("sensor", "frequency_hz", "amplitude")
OPTIONAL_COLUMNS = ("real", "imag")
COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
SUPPORTED_SUFFIXES = (".csv", ".parquet", ".uff", ".unv")
#: Allowed relative gap between ``amplitude`` and ``hypot(real, imag)``.
AMPLITUDE_RTOL = 1e-6
#: UFF58 record 6 as written here. The load is a combined load with no single
#: reference node, so the reference node is 0 and the load case is 1 (not 0,
#: which would declare a single-point excitation); the direction is +Z.
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


class MeasuredDataError(ValueError):
    """A measured-FRF file that does not follow the format.

    The message starts with the file and names the place of the first
    problem: a column, or a row as the user sees it in the file (for CSV the
    line number with the header as line 1; for Parquet the 1-based data row;
    for UFF the 1-based dataset and point).
    """


@dataclass(frozen=True, eq=False)
class MeasuredFRF:
    """Measured FRF amplitudes on a complete (frequency, sensor) grid.

    Arrays are read-only copies, checked on construction.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (p,), Hz
        Strictly increasing, > 0.
    sensors : ndarray, shape (n,), int
        Distinct 1-based sensor ids (ascending when read from a file).
    amplitude : ndarray, shape (p, n), m/N
        Modulus of the FRF, > 0; column ``j`` belongs to ``sensors[j]``.
    complex_frf : ndarray, shape (p, n), complex, m/N, or None
        The complex FRF when the file has it; ``abs(complex_frf)`` equals
        ``amplitude`` to ``AMPLITUDE_RTOL``.
    source : str
        Where the data came from (the file path), for messages.
    """

    frequencies_hz: np.ndarray
    sensors: np.ndarray
    amplitude: np.ndarray
    complex_frf: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        f = _read_only(self.frequencies_hz, float)
        raw_sensors = np.asarray(self.sensors)
        s = _read_only(raw_sensors, np.int64)
        a = _read_only(self.amplitude, float)
        c = None if self.complex_frf is None else _read_only(self.complex_frf, complex)
        if f.ndim != 1 or not np.all(np.isfinite(f) & (f > 0)) or np.any(np.diff(f) <= 0):
            raise ValueError("frequencies_hz must be 1-D, finite, > 0 and strictly increasing")
        if s.ndim != 1 or np.any(s != raw_sensors) or np.any(s < 1) or np.unique(s).size != s.size:
            raise ValueError("sensors must be 1-D distinct integers >= 1")
        if a.shape != (f.size, s.size) or not np.all(np.isfinite(a) & (a > 0)):
            raise ValueError(f"amplitude must be finite, > 0, shape {(f.size, s.size)}")
        if c is not None and (
            c.shape != a.shape
            or not np.all(np.isfinite(c))
            or np.any(np.abs(a - np.abs(c)) > AMPLITUDE_RTOL * np.abs(c))
        ):
            raise ValueError("complex_frf must be finite, shaped as amplitude, abs == amplitude")
        names = ("frequencies_hz", "sensors", "amplitude", "complex_frf")
        for name, value in zip(names, (f, s, a, c)):
            object.__setattr__(self, name, value)


def _read_only(values, dtype):
    array = np.array(values, dtype=dtype)
    array.setflags(write=False)
    return array


def read_measured(
    path, *, expected_sensors=None, expected_frequencies_hz=None, frequency_rtol=1e-9
):
    """Read and validate a measured-FRF file.

    Parameters
    ----------
    path : str or Path
        ``.csv``, ``.parquet``, ``.uff`` or ``.unv`` file (see module docstring).
    expected_sensors : sequence of int, shape (n,), optional
        If given, the file must hold exactly these sensors.
    expected_frequencies_hz : array_like, shape (p,), Hz, optional
        If given, the file must hold exactly these frequencies, each matched
        within ``frequency_rtol``. UFF keeps 6 significant digits of the
        frequency: use ``frequency_rtol=UFF_FREQUENCY_RTOL`` for UFF files.
        Without these two arguments a sensor or frequency missing from every
        row cannot be detected.
    frequency_rtol : float
        Relative tolerance for matching ``expected_frequencies_hz``.

    Returns
    -------
    MeasuredFRF
        Frequencies ascending, sensors ascending.

    Raises
    ------
    MeasuredDataError
        For any departure from the format, naming the file and the row or
        column (see the class docstring for how rows are counted).
    OSError
        If the file cannot be opened.
    """
    path = Path(path)
    suffix = _checked_suffix(path)
    if path.stat().st_size == 0:
        raise MeasuredDataError(f"{path}: empty file")
    reader = {".csv": _csv_columns, ".parquet": _parquet_columns}.get(suffix, _uff_columns)
    columns, where = reader(path)
    measured = _grid(columns, where, str(path))
    _check_expected(measured, expected_sensors, expected_frequencies_hz, frequency_rtol)
    return measured


def _checked_suffix(path):
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise MeasuredDataError(
            f"{path}: unsupported file extension {path.suffix!r};"
            f" supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    return suffix


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
    missing = [name for name in REQUIRED_COLUMNS if name not in names]
    if missing:
        listed = ", ".join(map(repr, missing))
        raise MeasuredDataError(f"{source}: missing required column(s) {listed}")
    if ("real" in names) != ("imag" in names):
        raise MeasuredDataError(f"{source}: columns 'real' and 'imag' go together, one is missing")


def _to_float(cells, name, where, source):
    """Parse cells one by one so that a bad one can be named."""
    values = np.empty(len(cells))
    for i, cell in enumerate(cells):
        if cell is None or (isinstance(cell, str) and not cell.strip()):
            raise MeasuredDataError(f"{source}: {where[i]}: {name} is empty")
        try:
            values[i] = float(cell)
        except (TypeError, ValueError):
            message = f"{source}: {where[i]}: {name} {cell!r} is not a number"
            raise MeasuredDataError(message) from None
    return values


def _csv_columns(path):
    records, where = [], []
    try:
        # utf-8-sig: spreadsheet programs put a byte-order mark before the header.
        with open(path, newline="", encoding="utf-8-sig") as fh:
            text = fh.read()
        if "\x00" in text:
            raise csv.Error("NUL byte in the file")
        reader = csv.reader(io.StringIO(text, newline=""))
        for record in reader:
            if record and not (len(record) == 1 and not record[0].strip()):
                records.append(record)
                where.append(f"line {reader.line_num}")
    except (UnicodeDecodeError, csv.Error) as exc:
        raise MeasuredDataError(f"{path}: not a CSV text table ({exc})") from None
    if not records:
        raise MeasuredDataError(f"{path}: empty file (no header line)")
    names = [name.strip() for name in records[0]]
    _check_header(names, path)
    for record, place in zip(records[1:], where[1:]):
        if len(record) != len(names):
            raise MeasuredDataError(
                f"{path}: {place}: {len(record)} fields, the header has {len(names)}"
            )
    where = where[1:]
    cells = list(zip(*records[1:])) or [()] * len(names)
    return {name: _to_float(col, name, where, path) for name, col in zip(names, cells)}, where


def _parquet_columns(path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise MeasuredDataError(f"{path}: not a Parquet table ({exc})") from None
    _check_header(list(table.column_names), path)
    where = [f"row {i + 1}" for i in range(table.num_rows)]
    columns = {}
    for name in table.column_names:
        values = table.column(name).to_numpy(zero_copy_only=False)
        numeric = values.dtype.kind in "iuf"
        columns[name] = values.astype(float) if numeric else _to_float(values, name, where, path)
    return columns, where


def _uff_columns(path):
    import pyuff

    try:
        uff = pyuff.UFF(str(path))
        types = list(uff.get_set_types())
    except Exception as exc:  # pyuff raises bare Exception
        raise MeasuredDataError(f"{path}: not a UFF file ({exc})") from None
    parts, where, kinds = [], [], set()
    for k, set_type in enumerate(types):
        if set_type != 58:
            continue
        try:
            dataset = uff.read_sets(k)
        except Exception as exc:
            message = f"{path}: dataset {k + 1}: unreadable dataset 58 ({exc})"
            raise MeasuredDataError(message) from None
        if dataset.get("func_type") != 4:  # e.g. coherence exported next to the FRFs
            logger.info("%s: dataset %d is not an FRF, skipped", path, k + 1)
            continue
        place = f"dataset {k + 1} (sensor {dataset['rsp_node']})"
        if dataset["rsp_dir"] != UFF_RESPONSE_DIRECTION:
            raise MeasuredDataError(
                f"{path}: {place}: response direction {dataset['rsp_dir']}, expected +Z (3)"
            )
        data = np.asarray(dataset["data"])
        kinds.add(np.iscomplexobj(data))
        if len(kinds) > 1:
            raise MeasuredDataError(f"{path}: {place}: real and complex FRFs mixed in one file")
        x = np.asarray(dataset["x"], dtype=float)
        # A dataset 58 abscissa runs upwards; one that does not is a damaged or mis-exported file.
        back = np.flatnonzero(~(np.diff(x) > 0))
        if back.size:
            j = back[0] + 1
            raise MeasuredDataError(
                f"{path}: {place} point {j + 1}: frequency {x[j]!r} Hz is not above the previous"
                f" point's {x[j - 1]!r} Hz (frequencies out of order)"
            )
        sensor = np.full(data.size, dataset["rsp_node"], dtype=float)
        parts.append((sensor, x, data))
        where += [f"{place} point {j + 1}" for j in range(data.size)]
    if not parts:
        raise MeasuredDataError(f"{path}: no FRF found (dataset 58 with function type 4)")
    sensor, frequency, data = (np.concatenate(column) for column in zip(*parts))
    columns = {"sensor": sensor, "frequency_hz": frequency, "amplitude": data}
    if np.iscomplexobj(data):
        columns.update(amplitude=np.abs(data), real=data.real.copy(), imag=data.imag.copy())
    return columns, where


def _first_bad(mask, values, problem, where, source):
    """Raise naming the first row where ``mask`` holds and how many more there are."""
    bad = np.flatnonzero(mask)
    if bad.size:
        more = f" ({bad.size - 1} more rows like it)" if bad.size > 1 else ""
        value = values[bad[0]].item()
        raise MeasuredDataError(f"{source}: {where[bad[0]]}: {problem.format(value)}{more}")


def _grid(columns, where, source):
    """Validate the long rows and reshape them to a MeasuredFRF."""
    if not where:
        raise MeasuredDataError(f"{source}: no data rows")
    for name, values in columns.items():
        _first_bad(~np.isfinite(values), values, name + " is {!r}", where, source)
    sensor, frequency, amplitude = (columns[name] for name in REQUIRED_COLUMNS)
    not_id = (sensor < 1) | (sensor != np.round(sensor))
    _first_bad(not_id, sensor, "sensor {!r} is not an integer >= 1", where, source)
    _first_bad(frequency <= 0, frequency, "frequency_hz {!r} is not > 0", where, source)
    _first_bad(amplitude <= 0, amplitude, "amplitude {!r} is not > 0", where, source)
    complex_frf = None
    if "real" in columns:
        complex_frf = columns["real"] + 1j * columns["imag"]
        modulus = np.abs(complex_frf)
        with np.errstate(divide="ignore"):  # real = imag = 0 gives gap inf: reported
            gap = np.abs(amplitude - modulus) / modulus
        problem = "amplitude and hypot(real, imag) differ by {:.2g} (relative)"
        _first_bad(gap > AMPLITUDE_RTOL, gap, problem, where, source)
    sensor = sensor.astype(np.int64)
    first_row = {}
    for i, key in enumerate(zip(sensor.tolist(), frequency.tolist())):
        if key in first_row:
            raise MeasuredDataError(
                f"{source}: {where[first_row[key]]} and {where[i]} both give"
                f" sensor {key[0]} at frequency_hz {key[1]!r}"
            )
        first_row[key] = i
    sensors, frequencies = np.unique(sensor), np.unique(frequency)
    if len(first_row) != sensors.size * frequencies.size:
        grid = ((s, f) for s in sensors.tolist() for f in frequencies.tolist())
        missing = [key for key in grid if key not in first_row]
        raise MeasuredDataError(
            f"{source}: incomplete grid: sensor {missing[0][0]} has no row at frequency_hz"
            f" {missing[0][1]!r} ({len(missing)} of {sensors.size} x {frequencies.size} missing)"
        )
    order = np.lexsort((sensor, frequency))  # frequency-major, so reshape gives (p, n)
    shape = (frequencies.size, sensors.size)
    return MeasuredFRF(
        frequencies_hz=frequencies,
        sensors=sensors,
        amplitude=amplitude[order].reshape(shape),
        complex_frf=None if complex_frf is None else complex_frf[order].reshape(shape),
        source=source,
    )


def _check_expected(measured, expected_sensors, expected_frequencies_hz, rtol):
    source = measured.source
    if expected_sensors is not None:
        want, have = {int(s) for s in expected_sensors}, set(measured.sensors.tolist())
        if want != have:
            raise MeasuredDataError(
                f"{source}: sensors differ from the expected ones: missing {sorted(want - have)},"
                f" unexpected {sorted(have - want)}"
            )
    if expected_frequencies_hz is not None:
        want = np.asarray(expected_frequencies_hz, dtype=float).ravel()
        have = measured.frequencies_hz
        close = np.abs(want[:, None] - have[None, :]) <= rtol * np.abs(want[:, None])
        missing, extra = want[~close.any(axis=1)], have[~close.any(axis=0)]
        if missing.size or extra.size:
            raise MeasuredDataError(
                f"{source}: frequencies differ from the expected ones (rtol {rtol:g}): missing"
                f" {missing.tolist()} Hz, unexpected {extra.tolist()} Hz"
            )


def write_measured(path, measured):
    """Write measured FRFs in the format chosen by the file extension.

    The file is written to a temporary name in the same folder and then
    moved into place with ``os.replace``, so a reader never sees half a file.

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.parquet``: the long table, columns in the order
        ``COLUMNS``, ``real``/``imag`` only when ``measured.complex_frf``
        exists, rows frequency-major. ``.uff``/``.unv``: one ASCII dataset 58
        per sensor: function type 4 (FRF), response node = sensor id,
        direction +Z, reference node ``UFF_REFERENCE_NODE`` (0: the combined
        load has no single reference node) with load case ``UFF_LOAD_CASE``,
        uneven abscissa (spacing 0) in Hz, ordinate complex double (type 6)
        or, without complex data, real double amplitude (type 4).
    measured : MeasuredFRF

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MeasuredDataError
        For an unsupported extension.
    ValueError
        For UFF, if there are fewer than two frequencies (pyuff derives an
        increment from the first two) or if two frequencies coincide at the 6
        significant digits that UFF keeps.
    """
    path = Path(path)
    suffix = _checked_suffix(path)
    writer = {".csv": _write_csv, ".parquet": _write_parquet}.get(suffix, _write_uff)
    if writer is _write_uff:
        _check_uff_frequencies(measured.frequencies_hz, path)
    temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        writer(temporary, measured)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path


def _table_columns(measured):
    p, n = measured.amplitude.shape
    columns = {
        "sensor": np.tile(measured.sensors, p),
        "frequency_hz": np.repeat(measured.frequencies_hz, n),
        "amplitude": measured.amplitude.ravel(),
    }
    if measured.complex_frf is not None:
        frf = measured.complex_frf.ravel()
        columns.update(real=frf.real, imag=frf.imag)
    return columns


def _write_csv(path, measured):
    columns = _table_columns(measured)
    with open(path, "x", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        # tolist() gives Python floats, which csv writes with repr: exact round trip.
        writer.writerows(zip(*(values.tolist() for values in columns.values())))


def _write_parquet(path, measured):
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table(_table_columns(measured)), path)


def _check_uff_frequencies(frequencies, path):
    stored = np.array([float(f"{f:13.5e}") for f in frequencies])  # as pyuff writes them
    if frequencies.size < 2 or np.unique(stored).size != frequencies.size:
        raise ValueError(f"{path}: UFF58 needs two or more frequencies distinct at 6 digits")
    change = np.max(np.abs(stored - frequencies) / frequencies)
    if change > 0:
        logger.warning("%s: UFF58 keeps 6 digits of frequency, changed by %.1e", path, change)


def _write_uff(path, measured):
    import pyuff

    frequencies = measured.frequencies_hz
    ordinates = measured.amplitude if measured.complex_frf is None else measured.complex_frf
    datasets = []
    for j, sensor in enumerate(measured.sensors.tolist()):
        datasets.append(
            pyuff.prepare_58(
                binary=0, id1="measured FRF", func_type=4, load_case_id=UFF_LOAD_CASE,
                rsp_node=sensor, rsp_dir=UFF_RESPONSE_DIRECTION,
                ref_node=UFF_REFERENCE_NODE, ref_dir=UFF_REFERENCE_DIRECTION,
                abscissa_spacing=0, abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
                ordinate_spec_data_type=8, orddenom_spec_data_type=13,
                ordinate_axis_units_lab="m/N", data=ordinates[:, j].copy(), x=frequencies.copy(),
            )
        )
    # force_double: types 4/6 (12 digits); single precision 2/5 keeps only 6.
    pyuff.UFF(str(path)).write_sets(datasets, mode="overwrite", force_double=True)


def describe(measured):
    """One-line summary: sensors, frequencies, range, complex or not."""
    f, s, a = measured.frequencies_hz, measured.sensors, measured.amplitude
    kind = "complex FRF" if measured.complex_frf is not None else "amplitude only"
    return (
        f"{measured.source}: {s.size} sensors ({s.min()}..{s.max()}), {f.size} frequencies"
        f" ({f[0]:g}..{f[-1]:g} Hz), amplitude {a.min():.3g}..{a.max():.3g} m/N, {kind}"
    )


def main(argv=None):
    """Validate a file: print a summary and return 0, or the error and 2."""
    parser = argparse.ArgumentParser(
        prog="python -m tasks.io.measured", description=__doc__.splitlines()[0]
    )
    parser.add_argument("path", help="measured-FRF file (.csv, .parquet, .uff, .unv)")
    args = parser.parse_args(argv)
    try:
        print(describe(read_measured(args.path)))
    except (MeasuredDataError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
