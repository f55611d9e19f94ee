"""The text of a measured table and of a UFF file, opened once for every reader of them.

:func:`csv_lines` reads a CSV text table as test systems and spreadsheets write it (a byte-order mark before the
header, blank lines, ``#`` comment lines carrying declarations); :func:`open_uff` opens a universal file. Both
turn what the libraries raise into :class:`~.frf.MeasuredDataError` naming the file.
"""

from __future__ import annotations

import csv
import io

from .frf import MeasuredDataError

__all__ = ["csv_lines", "open_uff"]


def csv_lines(path) -> tuple[list[list[str]], list[str], list[tuple[str, str, int]]]:
    """``(records, where, comments)`` of the CSV text table at ``path``.

    records : the non-blank, non-comment lines split into fields (the header first); where : ``"line N"`` of each;
    comments : ``(text, "line N", records before it)`` of each ``#`` line, its text stripped (a declaration's
    reader decides whether one after the data rows is allowed). Raises MeasuredDataError when the file is not
    UTF-8 text or holds a NUL byte."""
    records, where, comments = [], [], []
    try:
        # utf-8-sig: spreadsheet programs put a byte-order mark before the header.
        with open(path, newline="", encoding="utf-8-sig") as fh:
            text = fh.read()
        if "\x00" in text:
            raise csv.Error("NUL byte in the file")
        reader = csv.reader(io.StringIO(text, newline=""))
        for record in reader:
            if not record or (len(record) == 1 and not record[0].strip()):
                continue
            if record[0].lstrip().startswith("#"):
                comments.append((",".join(record).strip(), f"line {reader.line_num}", len(records)))
                continue
            records.append(record)
            where.append(f"line {reader.line_num}")
    except (UnicodeDecodeError, csv.Error) as exc:
        raise MeasuredDataError(f"{path}: not a CSV text table ({exc})") from None
    return records, where, comments


def open_uff(path):
    """``(pyuff.UFF, the dataset types)`` of the universal file at ``path``."""
    import pyuff

    try:
        uff = pyuff.UFF(str(path))
        types = list(uff.get_set_types())
    except Exception as exc:  # pyuff raises bare Exception
        raise MeasuredDataError(f"{path}: not a UFF file ({exc})") from None
    return uff, types
