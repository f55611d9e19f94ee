"""``python -m tasks.io.measured FILE``: validate a measured-FRF file, print a summary and what was converted.

Raw hammer records (:mod:`.time_records`) are turned into FRFs with the processing options given
(``--force-window``, ``--exponential-end``, ``--record``, ``--line-spacing``, ``--band``); ``--write OUT``
writes the result (FRFs, coherence, averages) as an FRF file for ``python -m flows.update --measured OUT``.
"""

from __future__ import annotations

import argparse
import sys

from tasks.io.measured import MeasuredDataError, RecordOptions, describe, read_measured, write_measured


def main(argv=None) -> int:
    """Validate a file: print a summary and return 0, or the error and 2."""
    parser = argparse.ArgumentParser(
        prog="python -m tasks.io.measured", description="Validate a measured-FRF file (.csv, .parquet, .uff, .unv)."
    )
    parser.add_argument("path", help="measured-FRF file (.csv, .parquet, .uff, .unv) or raw hammer records")
    parser.add_argument("--averages", type=int, metavar="N", help="averages behind each FRF where the file says none")
    raw = parser.add_argument_group("raw hammer records (time records, tables of samples)")
    raw.add_argument("--force-window", type=float, metavar="S", help="length of the rectangular force window, s "
                     "(default: one pulse width before the pulse to two after, at least 16 samples each side)")
    raw.add_argument("--exponential-end", type=float, metavar="E", help="exponential window on force and "
                     "responses, E at the record's end, e.g. 0.01 (default none; adds damping, noted)")
    raw.add_argument("--record", type=float, metavar="S", help="use the first S seconds of each record")
    raw.add_argument("--line-spacing", type=float, metavar="DF", help="line spacing, Hz (default 1 / record length)")
    raw.add_argument("--band", metavar="LO-HI", help="lines kept, Hz (default above 0 up to the sample rate / 2.56)")
    parser.add_argument("--write", metavar="OUT", help="write what was read as an FRF file (.uff, .csv, .parquet)")
    args = parser.parse_args(argv)
    from tasks.io.measured.modes import describe_modes, is_modal_file, read_modes

    if is_modal_file(args.path):  # measured modes (UFF dataset 55, the modal CSV): docs/guide/modal-data.md
        try:
            modes = read_modes(args.path)
        except (MeasuredDataError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(describe_modes(modes))
        return 0
    try:
        band = None
        if args.band is not None:
            try:
                band = tuple(float(v) for v in args.band.split("-"))
            except ValueError:
                band = (args.band,)
            if len(band) != 2:
                raise MeasuredDataError(f"--band {args.band!r}: give LO-HI in Hz, e.g. 0-400")
        options = RecordOptions(force_window_s=args.force_window, exponential_end=args.exponential_end,
                                record_s=args.record, line_spacing_hz=args.line_spacing, band_hz=band)
        measured = read_measured(args.path, averages=args.averages, records=options)
        if args.write:
            write_measured(args.write, measured)
    except (MeasuredDataError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(describe(measured))
    for note in measured.notes:
        print(f"  {note}")
    if args.write:
        print(f"wrote {args.write}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
