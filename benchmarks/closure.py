"""Closing the loop on the data sets of ``data/effects``: found effect against the truth, and time.

    OMP_NUM_THREADS=1 python -m benchmarks.closure                  # every data set
    OMP_NUM_THREADS=1 python -m benchmarks.closure point_mass.csv    # one
    OMP_NUM_THREADS=1 python -m benchmarks.closure --speed           # FRF with each effect vs base
    OMP_NUM_THREADS=1 python -m benchmarks.closure --table           # data/effects2: docs/closure2.md

Each closure starts from the nominal model (alpha = 0) with the cheap
multi-start least-squares update of :func:`fe_core.closure.multistart_update`
(the start plus two Sobol points) in place of an MRGP run, with the noise level
configured at 0.5 %. The truth (``data/effects/truth.json``) is read here,
for the comparison only.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from fe_core.benchmark import three_plate
from fe_core.closure import close_loop
from fe_core.residual import overall_error
from tasks.io.measured import read_measured

DATA = Path(__file__).resolve().parents[1] / "data" / "effects"
#: Settings shared with the tests (tests/fe_core/test_closure.py).
SETTINGS = dict(noise=0.005, restarts=2, per_type=1)


def location_error(model, truth: dict, found: str | None) -> dict:
    """Distance of the found location from the truth: in elements (nodes) or same/different label."""
    if found is None:
        return {"same": False}
    if "node" in truth:
        if not found.startswith("node "):
            return {"same": False}
        a = model.mesh.nodes[truth["node"]]
        b = model.mesh.nodes[int(found.split()[1])]
        # Element size near the truth: the spacing of the mesh's node lines there.
        xs = np.unique(np.round(model.mesh.nodes[:, 0], 9))
        ys = np.unique(np.round(model.mesh.nodes[:, 1], 9))
        dx = np.min(np.abs(np.diff(xs)[np.searchsorted(xs, a[0]) - 1: np.searchsorted(xs, a[0]) + 1]))
        dy = np.min(np.diff(ys))
        elements = max(abs(b[0] - a[0]) / dx, abs(b[1] - a[1]) / dy)
        return {"same": int(found.split()[1]) == truth["node"], "elements": float(elements),
                "dx_mm": float(1e3 * (b[0] - a[0])), "dy_mm": float(1e3 * (b[1] - a[1]))}
    return {"same": found == truth["location"]}


def run_one(path: Path, truth: dict, settings: dict | None = None) -> dict:
    model = three_plate()
    measured = read_measured(path)
    t0 = time.perf_counter()
    result = close_loop(model, measured.frequencies_hz, measured.amplitude, np.zeros(model.n_segments),
                        **(settings or SETTINGS))
    seconds = time.perf_counter() - t0
    u = measured.amplitude
    row = {
        "data": path.name,
        "true_effect": truth.get("effect"),
        "true_location": truth.get("location"),
        "true_value": truth.get("value"),
        "first": result.candidates[0].effect if result.candidates else None,
        "first_location": result.candidates[0].location if result.candidates else None,
        "added": None if result.chosen is None else result.chosen.effect,
        "location": None if result.chosen is None else result.chosen.location,
        "value": None if result.chosen is None else float(result.chosen.fit.values[0]),
        "error_before": overall_error(result.baseline.relative(u)),
        "error_after": overall_error(result.final.relative(u)),
        "noise_floor": result.before.noise_floor,
        "p_before": result.before.p_chi2,
        "p_after": result.after.p_chi2,
        "seconds": seconds,
        "fe_solves": result.baseline.evaluations + sum(c.fit.evaluations for c in result.candidates if c.fit),
    }
    if truth.get("effect"):
        row["location_error"] = location_error(model, truth, row["location"])
        row["value_error"] = None if row["value"] is None else abs(row["value"] / truth["value"] - 1.0)
    return row


def speed(repeats: int = 21) -> list[dict]:
    """Median time of the base FRF, the FRF with each effect, and one screening of every candidate."""
    from benchmarks.timing import median_time
    from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as F
    from fe_core.closure import Fit, screen
    from fe_core.effects import Applied, build_library, extended_frf
    from fe_core.residual import log_residual

    model = three_plate()
    library = build_library(model)
    examples = {"point_mass": ("node 337", 0.12), "grounded_spring": ("node 633", 4e5),
                "joint_band": ("joint x=230 mm", -0.75), "segment_mass": ("segment5", 0.3), "damping": ("b", 3e-5)}
    rows = [{"what": "model.frf (base)", "seconds": median_time(lambda: model.frf(ALPHA_ACTUAL, F), repeats)}]
    for effect in library:
        loc, value = examples[effect.kind]
        applied = [Applied(effect, loc, np.array([value]))]
        rows.append({"what": f"extended_frf + {effect.kind}",
                     "seconds": median_time(lambda: extended_frf(model, ALPHA_ACTUAL, F, applied), repeats)})
    u = np.abs(model.frf(ALPHA_ACTUAL, F)) * 1.01
    amp = np.abs(model.frf(ALPHA_ACTUAL, F))
    base = Fit(alpha=ALPHA_ACTUAL.copy(), effect=None, location=None, values=np.zeros(0), model_amplitude=amp,
               residual=log_residual(amp, u), evaluations=0)
    n = sum(len(e.locations()) for e in library)
    rows.append({"what": f"screen: all {n} candidates (one 6-load field solve)",
                 "seconds": median_time(lambda: screen(model, F, base, library), max(3, repeats // 5))})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.closure", description=__doc__.splitlines()[0])
    p.add_argument("files", nargs="*", help="data file names in data/effects (default: all)")
    p.add_argument("--speed", action="store_true", help="time the extended FRF and the screening instead")
    p.add_argument("--table", action="store_true",
                   help="forward selection on every data set of data/effects2; markdown table to docs/closure2.md")
    args = p.parse_args(argv)
    if args.table:
        return table(args.files)
    if args.speed:
        for row in speed():
            print(f"{row['what']:<50} {1e3 * row['seconds']:8.1f} ms")
        return 0
    truth = json.loads((DATA / "truth.json").read_text())["data"]
    names = args.files or list(truth)
    rows = []
    for name in names:
        row = run_one(DATA / name, truth[name])
        rows.append(row)
        loc = row.get("location_error", {})
        value = "-" if row["value"] is None else f"{row['value']:.4g}"
        verr = "-" if row.get("value_error") is None else f"{row['value_error']:.1%}"
        print(f"{row['data']:22s} first {row['first']}/{row['first_location']}  added {row['added']} "
              f"at {row['location']} = {value} (true {row['true_value']} at {row['true_location']}; "
              f"value error {verr}, location {loc})  error {row['error_before']:.3%} -> {row['error_after']:.3%} "
              f"(noise floor {row['noise_floor']:.3%})  {row['seconds']:.1f} s, {row['fe_solves']} FE solves",
              flush=True)
    print(json.dumps(rows, indent=1))
    return 0


def _truth_text(entry: dict) -> str:
    effects = entry["effects"]
    if not effects:
        return "none"
    return "; ".join(f"{e['effect']} {e['location']} = {e['value']:.4g} {e['unit']}" for e in effects)


def table(files: list[str] | None = None) -> int:
    """The issue-18 table: truth, verdict, effects added (in order), error before -> after, seconds."""
    data2 = DATA.parent / "effects2"
    truth = json.loads((data2 / "truth.json").read_text())["data"]
    model = three_plate()
    lines = ["| data | truth | verdict | effects added (in order, final joint values) | implausible fits | "
             "error before -> after | noise floor | s |", "|" + "---|" * 8]
    for name in files or list(truth):
        measured = read_measured(data2 / name)
        t0 = time.perf_counter()
        result = close_loop(model, measured.frequencies_hz, measured.amplitude, np.zeros(model.n_segments),
                            **SETTINGS)
        seconds = time.perf_counter() - t0
        u = measured.amplitude
        added = "; ".join(f"{a.effect.kind} {a.location} = {a.values[0]:.4g} {a.effect.units[0]} "
                          f"({c.explained:.0%})" for c, a in zip(result.steps, result.final.applied)) or "-"
        bad = "; ".join(f"{c.effect} {c.location} = {c.fit.values[0]:.4g}" for c in result.implausible[:3]) or "-"
        line = (f"| {name} | {_truth_text(truth[name])} | {result.verdict} | {added} | {bad} | "
                f"{overall_error(result.baseline.relative(u)):.2%} -> {overall_error(result.final.relative(u)):.2%} | "
                f"{result.before.noise_floor:.2%} | {seconds:.0f} |")
        lines.append(line)
        print(line, flush=True)
    out = Path(__file__).resolve().parents[1] / "docs" / "closure2.md"
    out.write_text("# Closing the loop, second round (data/effects2)\n\nWritten by `python -m benchmarks.closure "
                   "--table` (one core, OPENBLAS_NUM_THREADS=1), settings " + json.dumps(SETTINGS)
                   + ", forward selection up to 3 effects, every registered effect kind.\n\n" + "\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
