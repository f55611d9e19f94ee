"""Why a held-out case missed: the truth's effect fitted at its own place against the effect the closure found.

For a case the closure did not explain at the true place and size, the two fits are made on the full FE model from
the closure's final factors, each with alpha refitted (:func:`fe_core.closure.fits.fit_update`, exact Jacobian):
the true effect at its place (the truth's location when the library has it, else the kind's location nearest the
truth's position) from its true size, and the found one from its size. Which leaves the smaller sum of squares
tells the two kinds of miss apart:

- the truth fits **better**: the data single out the truth on this model and the closure's search did not reach it
  (a search miss: more places, better evaluations, other starts would find it);
- the truth fits **worse**: the model, with its own error (mesh, parametrisation), prefers another place, size or
  kind; no search on this model finds the truth (a model-error miss: a finer model, or the bar, is the lever);
- within :data:`TIE` of each other: a tie, the data do not tell the places apart (the miss is elsewhere: a size
  moved by a second effect, a place between nodes).

The alpha-only fit from the same factors is given beside them (what the effect explains).

    python -m benchmarks.truth_check --runs <the set's runs folder> --cases <the set's cases folder> hk07 hk10

Prints one row per case (sums of squares of ln|Z| over the closure's lines, the sizes and the factors' distance
from the truth); a benchmark (minutes per case on a 25k-DOF model), not a test.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd

from fe_core.closure.effects import build_library
from fe_core.closure.fits import fit_update
from fe_core.io.model_toml import read_model_toml

__all__ = ["closure_data", "true_location", "check_case", "TIE"]

#: Sums of squares within this share of each other are a tie: the data do not tell the two places apart on this
#: model (the fits converge to 1e-8; a share of a per cent is far beyond the optimiser and within any noise).
TIE = 0.01


def closure_data(run: Path):
    """(frequencies, amplitudes (p, n), the closure's record) of a kept run folder: the lines the closure fitted."""
    t = pd.read_parquet(run / "closure" / "frf_closure.parquet")
    # the channels in the table's order (the closure's), not pivot's sorted one ("S10" before "S2")
    u = t.pivot(index="frequency_hz", columns="sensor", values="measured")[list(pd.unique(t["sensor"]))]
    return u.index.to_numpy(float), u.to_numpy(float), json.loads((run / "closure" / "closure.json").read_text())


def true_location(model, effect, truth_effect: dict) -> str:
    """The truth's location in the library (``truth_effect["location"]`` when the kind has it), else the kind's
    location nearest the truth's position with the same suffix (a patch's radius)."""
    locations = effect.locations()
    if truth_effect["location"] in locations:
        return truth_effect["location"]
    xyz = np.asarray(truth_effect.get("model_node_xyz_m", truth_effect["xyz_m"]), float)
    suffix = truth_effect["location"].split()[2:]
    best, dist = None, np.inf
    for loc in locations:
        parts = loc.split()
        if parts[2:] != suffix or not re.fullmatch(r"\d+", parts[1]):
            continue
        p = model.node_position(int(parts[1]))
        d = np.inf if p is None else float(np.linalg.norm(p - xyz))
        if d < dist:
            best, dist = loc, d
    if best is None:
        raise ValueError(f"no location of {effect.kind} near the truth's {truth_effect['location']}")
    return best


def check_case(run: Path, truth: dict, model=None) -> dict:
    """The truth's effect and the closure's first effect, each fitted from the closure's final factors."""
    freqs, u, closure = closure_data(run)
    if model is None:
        model = read_model_toml(json.loads((run / "manifest.json").read_text())["config"]["model"])
    e = truth["effect"]
    library = {x.kind: x for x in build_library(model)}
    kind = e.get("library_kind", e["kind"])
    if kind == "grounded_spring" and kind not in library:
        kind = f"grounded_spring_{e.get('axis', 'z')}"
    a0 = np.array([v for k, v in closure["parameters_after"].items() if k.startswith("alpha_")])
    truth_alpha = np.asarray(truth["factors"], float)
    row = {"case": truth["case"], "verdict": closure["verdict"],
           "alpha_only_rss": float(fit_update(model, freqs, u, a0).rss)}
    fits = []
    if kind in library:
        loc = true_location(model, library[kind], e)
        fits.append(("truth", library[kind], loc, float(e["value"])))
    found = (closure.get("effects") or [None])[0]
    if found is not None and found["type"] in library:
        fits.append(("found", library[found["type"]], found["location"], float(found["value"])))
    for name, effect, loc, value in fits:
        f = fit_update(model, freqs, u, a0, effect=effect, location=loc, value0=np.atleast_1d(value))
        row[name] = {"effect": effect.kind, "location": loc, "value": float(f.values[0]), "rss": float(f.rss),
                     "alpha_from_truth": float(np.max(np.abs(f.alpha - truth_alpha)))}
    if "truth" in row and "found" in row:
        t, f = row["truth"]["rss"], row["found"]["rss"]
        row["miss"] = "tie" if abs(t - f) <= TIE * min(t, f) else "search" if t < f else "model error"
    return row


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, required=True, help="the kept run folders (benchmarks.heldout --keep)")
    p.add_argument("--cases", type=Path, required=True, help="the set's cases folder (each case's truth.json)")
    p.add_argument("cases_", nargs="+", metavar="CASE")
    args = p.parse_args(argv)
    for case in args.cases_:
        truth = json.loads((args.cases / case / "truth.json").read_text())
        print(json.dumps(check_case(args.runs / case, truth)), flush=True)


if __name__ == "__main__":
    main()
