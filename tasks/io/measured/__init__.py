"""Measured FRFs: one internal form, one reader/writer module per file format.

- :mod:`.frf`: the internal form :class:`MeasuredFRF` (receptance on a
  complete (line, channel) grid, channels = (response, reference) pairs,
  optional complex values and coherence, what was converted), the FRF kinds
  and channel labels, and the checks shared by every format;
- :mod:`.table`: long tables, CSV and Parquet (see its docstring for the
  columns; the legacy ``sensor, frequency_hz, amplitude[, real, imag]`` table
  reads as before);
- :mod:`.uff`: Universal File Format dataset 58 (FRFs and coherence; response
  and reference nodes and directions, ordinate kind; the number of averages from the ID lines).
- :mod:`.time_records`: raw hammer records, UFF58 time records (function type 1) or a table of samples
  (a ``time`` column), turned into H1 FRFs with coherence over the hits by :mod:`.records`.

- :mod:`.units`: the units labels test systems write (``g``, ``mm/s``,
  ``lbf``, ...), UFF58 records 8-10 and dataset 164; every value is converted
  to SI and the conversion noted, an unknown or contradicting label refused;
- :mod:`.problems`: every problem of a file collected and reported at once.

``read_measured`` and ``write_measured`` pick the module by the file's
extension. Problems raise one :class:`MeasuredDataError` naming the file and
the place of each (CSV ``line k`` with the header as line 1, Parquet ``row k``,
UFF ``dataset k`` and ``point j``): up to 20 listed, then how many more. ``python -m tasks.io.measured FILE``
validates a file. Matching channels to a model's sensors and excitations is
not done here (the data alone do not know the model): see
:mod:`tasks.update_data`.

Example::

    from tasks.io.measured import read_measured, write_measured
    m = read_measured("data/benchmark/hammer.uff")      # accelerance in the file, receptance here
    write_measured("hammer_mobility.csv", m, kind="mobility")
"""

from __future__ import annotations

import logging
import os
import uuid
from pathlib import Path

import numpy as np

import dataclasses

from tasks.io.measured import table, time_records, uff
from tasks.io.measured.frf import (AMPLITUDE_RTOL, KINDS, MeasuredDataError, MeasuredFRF, dof_label, kind_of,
                                   parse_dof)
from tasks.io.measured.records import RecordOptions
from tasks.io.measured.table import COLUMNS, LEGACY_COLUMNS
from tasks.io.measured.uff import UFF_FREQUENCY_RTOL, UFF_ORDINATE_RTOL

__all__ = [
    "MeasuredFRF", "MeasuredDataError", "read_measured", "write_measured", "describe", "main", "KINDS",
    "AMPLITUDE_RTOL", "UFF_FREQUENCY_RTOL", "UFF_ORDINATE_RTOL", "COLUMNS", "LEGACY_COLUMNS", "FORMATS",
    "SUPPORTED_SUFFIXES", "parse_dof", "dof_label", "kind_of", "RecordOptions",
]

logger = logging.getLogger(__name__)

#: File extension -> (reader ``read(path)``, writer ``write(path, measured, kind)``) of its format module.
FORMATS = {
    ".csv": (table.read_csv, table.write_csv),
    ".parquet": (table.read_parquet, table.write_parquet),
    ".uff": (uff.read, uff.write),
    ".unv": (uff.read, uff.write),
}
SUPPORTED_SUFFIXES = tuple(FORMATS)


def _checked_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise MeasuredDataError(
            f"{path}: unsupported file extension {path.suffix!r};"
            f" supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    return suffix


def read_measured(path, *, expected_sensors=None, expected_frequencies_hz=None, frequency_rtol=1e-9, averages=None,
                  records: RecordOptions | None = None):
    """Read and validate a measured-FRF file.

    Parameters
    ----------
    path : str or Path
        ``.csv``, ``.parquet``, ``.uff`` or ``.unv`` file.
    expected_sensors : sequence of int, shape (n,), optional
        If given, the file must hold exactly these channel numbers (legacy
        form: sensors).
    expected_frequencies_hz : array_like, shape (p,), Hz, optional
        If given, the file must hold exactly these frequencies, each matched
        within ``frequency_rtol``. UFF keeps 6 significant digits of an
        uneven abscissa: use ``frequency_rtol=UFF_FREQUENCY_RTOL`` for UFF files.
    frequency_rtol : float
    averages : int, optional
        The number of averages behind every channel when the file states none (``--averages``); a file that
        states its own keeps them (noted when they differ).
    records : RecordOptions, optional
        How raw records (:mod:`.time_records`) become FRFs: windows, record length, line spacing, band;
        default :class:`RecordOptions` ().

    Returns
    -------
    MeasuredFRF
        Receptance; frequencies ascending; legacy sensors ascending, other
        channels in file order. What was converted is in ``notes`` (and logged).

    Raises
    ------
    MeasuredDataError
        For any departure from the format, naming the file and the place.
    OSError
        If the file cannot be opened.
    """
    path = Path(path)
    suffix = _checked_suffix(path)
    if path.stat().st_size == 0:
        raise MeasuredDataError(f"{path}: empty file")
    if time_records.is_time_records(path):
        measured = time_records.read(path, records)
    else:
        measured = FORMATS[suffix][0](path)
    measured = _with_averages(measured, averages)
    _check_expected(measured, expected_sensors, expected_frequencies_hz, frequency_rtol)
    for note in measured.notes:
        logger.info("%s: %s", path, note)
    return measured


def _with_averages(measured: MeasuredFRF, averages) -> MeasuredFRF:
    """Fill the number of averages from the user where the file states none; note a disagreement."""
    if averages is None:
        return measured
    if measured.averages is None:
        return dataclasses.replace(measured, averages=np.full(measured.n_channels, int(averages)),
                                   notes=measured.notes + (f"number of averages {int(averages)} as given (the file "
                                                           "states none)",))
    if np.any(measured.averages != int(averages)):
        stated = ", ".join(map(str, sorted(set(measured.averages.tolist()))))
        return dataclasses.replace(measured, notes=measured.notes + (
            f"the file states {stated} averages; the {int(averages)} given are not used",))
    return measured


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


def write_measured(path, measured: MeasuredFRF, kind: str | None = None):
    """Write measured FRFs in the format chosen by the file extension.

    The file is written to a temporary name in the same folder and then
    moved into place with ``os.replace``, so a reader never sees half a file.

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.parquet``: the long table (:mod:`.table`), rows
        frequency-major; the legacy form gives the legacy columns
        ``sensor, frequency_hz, amplitude[, real, imag]``. ``.uff``/``.unv``:
        one ASCII dataset 58 per channel, plus its coherence (:func:`.uff.write`;
        labelled channels with even spacing when the lines are evenly spaced).
    measured : MeasuredFRF
    kind : {"receptance", "mobility", "accelerance"}, optional
        Write every channel as this kind (default: the kind each was read as).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MeasuredDataError
        For an unsupported extension.
    ValueError
        For an unknown kind; for UFF, if uneven lines are fewer than two or
        two coincide at the 6 significant digits UFF keeps, or a channel has
        no ``NODE:DIR`` labels.
    """
    path = Path(path)
    suffix = _checked_suffix(path)
    if kind is not None and kind not in KINDS:
        raise ValueError(f"unknown FRF kind {kind!r}; choose one of {', '.join(KINDS)}")
    writer = FORMATS[suffix][1]
    options = {}
    if writer is uff.write:
        options["even"] = not measured.legacy and uff.is_even(measured.frequencies_hz)
        if not options["even"]:
            uff.check_uneven(measured.frequencies_hz, path)
    temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        writer(temporary, measured, kind, **options)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path


def describe(measured: MeasuredFRF) -> str:
    """One-line summary: channels, frequencies, range, complex or not, kinds, coherence."""
    f, s, a = measured.frequencies_hz, measured.sensors, measured.amplitude
    kind = "complex FRF" if measured.complex_frf is not None else "amplitude only"
    if measured.legacy:
        what = f"{s.size} sensors ({s.min()}..{s.max()})"
    else:
        refs = sorted({r or "default excitation" for r in measured.references})
        what = f"{s.size} channels ({len(set(measured.responses))} responses x {len(refs)} references: " \
               f"{', '.join(refs)})"
    extra = ""
    if measured.kinds:
        extra += ", read as " + "/".join(sorted(set(measured.kinds)))
    if measured.coherence is not None:
        extra += f", coherence {measured.coherence.min():.3g}..{measured.coherence.max():.3g}"
    if measured.averages is not None:
        counts = sorted(set(measured.averages.tolist()))
        extra += f", {'/'.join(map(str, counts))} averages"
    return (
        f"{measured.source}: {what}, {f.size} frequencies ({f[0]:g}..{f[-1]:g} Hz), receptance amplitude "
        f"{a.min():.3g}..{a.max():.3g} m/N, {kind}{extra}"
    )


def main(argv=None):
    """Validate a file: print a summary (and what was converted) and return 0, or the error and 2."""
    from tasks.io.measured.__main__ import main as cli

    return cli(argv)
