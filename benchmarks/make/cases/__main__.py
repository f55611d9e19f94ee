"""python -m benchmarks.make.cases --set SET [--only ID ...] [--structures] [--out DIR] (SET: one of `sets.SETS`)"""

from __future__ import annotations

import os

# One thread for MKL (PARDISO) and BLAS: a threaded factorisation sums in a varying order, and the eigenvectors,
# hence the 7th digit of the written FRF, then differ from run to run. Set before numpy is imported.
for _var in ("MKL_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from benchmarks.make.cases import __doc__ as DOC  # noqa: E402
from benchmarks.make.cases import build, case, sets  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.make.cases", description=DOC.split("\n\n")[0])
    p.add_argument("--set", choices=tuple(sets.SETS), help="the development set or a held-out set")
    p.add_argument("--only", nargs="+", metavar="ID", help="these cases of the set (default: all)")
    p.add_argument("--structures", action="store_true",
                   help="(re)build the structures' model files and structure.json (before the cases)")
    p.add_argument("--out", type=Path, default=case.ROOT, help=f"root folder (default {case.ROOT})")
    args = p.parse_args(argv)
    if not args.set and not args.structures:
        p.error(f"give --set {'|'.join(sets.SETS)} and/or --structures")
    if args.structures:
        names = sorted({c["structure"] for which in sets.SETS for c in sets.cases(which)})
        for name in names:
            t0 = time.perf_counter()
            info = build.structure_info(name, args.out, rebuild=True)
            print(f"{name}: model {info['model_free_dofs']} free DOFs, data {info['data']}; nominal model - data "
                  f"(%): {info['model_minus_data_percent'][:10]} ({time.perf_counter() - t0:.0f} s)", flush=True)
    if not args.set:
        return 0
    chosen = sets.cases(args.set)
    if args.only:
        unknown = sorted(set(args.only) - {c["id"] for c in chosen})
        if unknown:
            p.error(f"no case {', '.join(unknown)} in the {args.set} set (ids: {chosen[0]['id']}..{chosen[-1]['id']})")
        chosen = [c for c in chosen if c["id"] in args.only]
    for spec in chosen:
        truth = build.make_case(spec, args.out)
        e = truth["effect"]
        what = e["kind"] if e["kind"] == "none" else f"{e['kind']} {e.get('location', '')} {e.get('value', 0):.4g} {e.get('unit', '')}"
        print(f"{spec['id']} {spec['structure']}: {what}; {truth['lines']['count']} lines to "
              f"{truth['lines']['top_hz']:g} Hz; effect shift (bandwidths) "
              f"{max(map(abs, truth['effect_shift_in_half_power_bandwidths']), default=0):.2f}; check "
              f"{truth['check_equilibrium_residual']['largest_relative']:.1e}; {truth['seconds']:.0f} s", flush=True)
    index = args.out / args.set / "index.json"
    rows = {}
    if index.exists():
        rows = {r["id"]: r for r in json.loads(index.read_text())["cases"]}
    for spec in sets.cases(args.set):
        t = args.out / args.set / spec["id"] / "truth.json"
        if t.exists():
            truth = json.loads(t.read_text())
            rows[spec["id"]] = {**spec, "measured_sha256": truth["measured_sha256"]}
    index.write_text(json.dumps({"set": args.set, "command": f"python -m benchmarks.make.cases --set {args.set}",
                                 "cases": [rows[k] for k in sorted(rows)]}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
