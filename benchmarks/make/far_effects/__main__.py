"""``python -m benchmarks.make.far_effects [CASE ...] [--root DIR]``: write the far-effect cases (all by default)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .cases import CASES
from .make import ROOT, renoise, write_case


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.make.far_effects", description=__doc__)
    p.add_argument("cases", nargs="*", help=f"cases (default all: {', '.join(CASES)})")
    p.add_argument("--root", type=Path, default=ROOT, help=f"where the case folders go (default {ROOT})")
    p.add_argument("--renoise", action="store_true", help="only the measured files again, from exact.npz")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    for name in args.cases or list(CASES):
        if name not in CASES:
            p.error(f"unknown case {name!r}; known: {', '.join(CASES)}")
        if args.renoise:
            renoise(CASES[name], args.root)
        else:
            write_case(CASES[name], args.root)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
