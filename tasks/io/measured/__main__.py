"""``python -m tasks.io.measured FILE``: validate a measured-FRF file, print a summary and what was converted."""

from __future__ import annotations

import argparse
import sys

from tasks.io.measured import MeasuredDataError, describe, read_measured


def main(argv=None) -> int:
    """Validate a file: print a summary and return 0, or the error and 2."""
    parser = argparse.ArgumentParser(
        prog="python -m tasks.io.measured", description="Validate a measured-FRF file (.csv, .parquet, .uff, .unv)."
    )
    parser.add_argument("path", help="measured-FRF file (.csv, .parquet, .uff, .unv)")
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
        measured = read_measured(args.path)
    except (MeasuredDataError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(describe(measured))
    for note in measured.notes:
        print(f"  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
