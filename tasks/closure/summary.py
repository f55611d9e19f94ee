"""What a closure reports: ``closure.json`` (the decision, the effects with their evidence and rivals,
errors and parameters before and after, the best candidates) and the ranked candidates' table."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from fe_core.closure import fits, screening
from fe_core.closure.selection import IDENTIFIED, spread_mm
from fe_core.inference.residual import overall_error, per_sensor_error

__all__ = ["CANDIDATES_IN_JSON", "LOCATIONS_IN_JSON"]


#: Candidates listed in closure.json (all of them are in candidates.parquet).
CANDIDATES_IN_JSON = 25
#: Locations of an added effect's kind listed with their evidence (of those holding 95 % of it).
LOCATIONS_IN_JSON = 10


def _candidates_frame(ranked: list[screening.Candidate], library: dict) -> pd.DataFrame:
    rows = []
    for k, c in enumerate(ranked, start=1):
        fit = c.fit
        rows.append({
            "rank": k, "effect": c.effect, "location": c.location, "n_locations": c.n_locations,
            "checked": fit is not None,
            "value": float(fit.values[0]) if fit is not None else float(c.linear_values[0]),
            "unit": _unit(library[c.effect], c.location),
            "explained": c.explained if fit is not None else np.nan,
            "delta_bic": c.delta_bic if fit is not None else np.nan,
            "delta_ebic": c.delta_ebic if fit is not None else np.nan,
            "linear_value": float(c.linear_values[0]), "linear_explained": c.linear_explained,
            "linear_delta_bic": c.linear_delta_bic, "linear_delta_ebic": c.linear_delta_ebic,
            "moved_from": json.dumps(c.moved_from),
            "fe_solves": fit.evaluations if fit is not None else 0,
        })
    return pd.DataFrame(rows)


def _effect_entry(c: screening.Candidate, library: dict, values=None) -> dict:
    eff = library[c.effect]
    v = c.fit.values if values is None else values
    return {"type": c.effect, "location": c.location,
            "value": float(v[0]) if eff.n_parameters == 1 else dict(zip(eff.parameters, map(float, v))),
            "parameter": eff.parameters[0], "unit": _unit(eff, c.location), "details": eff.describe(c.location)}


def _verdict_json(verdict: str, steps: list, implausible: list, library: dict, final: fits.Fit, sel=None) -> dict:
    """``verdict``, ``effects`` (in the order added, values of the final joint fit, each with the share of
    the residual it explained when added, its kind's share of the evidence among the kinds checked in
    its place and the rivals holding at least 1 % of it), ``implausible`` (fits that ended on a
    plausibility bound), ``swaps`` and ``moves`` (effects replaced or relocated on the way)."""
    finals = [a.values for a in final.applied] if steps else []
    weights = sel.weights if sel is not None else [1.0] * len(steps)
    rivals = sel.rivals if sel is not None else [[] for _ in steps]
    spreads = sel.spreads if sel is not None else [[] for _ in steps]
    where = sel.located if sel is not None else [True] * len(steps)
    effects = []
    for k, (c, v, w, rv, sp, at) in enumerate(zip(steps, finals, weights, rivals, spreads, where), start=1):
        entry = {**_effect_entry(c, library, v), "explained": c.explained, "delta_ebic": c.delta_ebic, "step": k,
                 "moved_from": list(c.moved_from),
                 "evidence": w, "located": bool(at), "identified": bool(w >= IDENTIFIED and at),
                 "rivals": [{"type": r.effect, "location": r.location, "value": float(r.values[0]),
                             "unit": _unit(library[r.effect], r.location), "delta_ebic": r.delta_ebic,
                             "evidence": r.weight} for r in rv],
                 "locations_95": len(sp), "spread_mm": spread_mm(library[c.effect], c.location, sp) if sp else None,
                 "locations": [{"location": loc, "evidence": wl} for loc, wl in sp[:LOCATIONS_IN_JSON]]}
        effects.append(entry)
    return {"verdict": verdict, "effects": effects,
            "implausible": [{**_effect_entry(c, library), "explained": c.explained} for c in implausible],
            "swaps": list(sel.swaps) if sel is not None else [], "moves": list(sel.moves) if sel is not None else []}


def _unit(effect, location) -> str:
    if effect.kind == "damping":
        return effect.describe(location)["unit"]
    return effect.units[0]


def _errors(fit, u, sensors):
    rel = fit.relative(u)
    return overall_error(rel), {f"sensor_{int(s)}": float(v) for s, v in zip(sensors, per_sensor_error(rel))}


def _params(fit, library) -> dict:
    out = {f"alpha_{i + 1}": float(v) for i, v in enumerate(fit.alpha)}
    for a in fit.applied:  # the effects in the order added; a second one of a kind is named by its location
        key = a.effect.kind if not any(f"{a.effect.kind}." in k for k in out) else f"{a.effect.kind}@{a.location}"
        out.update({f"{key}.{n}": float(v) for n, v in zip(a.effect.parameters, a.values)})
    return out


def _closure_json(store, settings, run_info, base, final, chosen, before, after, ranked, library, u, sensors,
                  freqs, before_info) -> dict:
    e_before, s_before = _errors(base, u, sensors)
    e_after, s_after = _errors(final, u, sensors)
    effect = None
    if chosen is not None:
        eff = library[chosen.effect]
        effect = {"type": chosen.effect, "location": chosen.location,
                  "value": float(chosen.fit.values[0]) if eff.n_parameters == 1 else
                  dict(zip(eff.parameters, map(float, chosen.fit.values))),
                  "parameter": eff.parameters[0], "unit": _unit(eff, chosen.location),
                  "details": eff.describe(chosen.location), "moved_from": chosen.moved_from,
                  "explained": chosen.explained, "delta_bic": chosen.delta_bic, "delta_ebic": chosen.delta_ebic}
    if chosen is not None:
        decision = (f"added {chosen.effect} at {chosen.location}: residual before is structure "
                    f"(chi-square p = {before.p_chi2:.3g}) and its extended BIC is {-chosen.delta_ebic:.1f} "
                    f"below the model without it")
    elif not before.structured:
        decision = f"no effect: the residual is noise (chi-square p = {before.p_chi2:.3g} >= {before.significance})"
    else:
        decision = "no effect: no checked candidate lowers the extended BIC"
    cands = []
    for k, c in enumerate(ranked[:CANDIDATES_IN_JSON], start=1):
        entry = {"rank": k, "type": c.effect, "location": c.location, "checked": c.fit is not None,
                 "value": float(c.fit.values[0]) if c.fit is not None else float(c.linear_values[0]),
                 "unit": _unit(library[c.effect], c.location),
                 "linear_explained": c.linear_explained, "linear_delta_ebic": c.linear_delta_ebic}
        if c.fit is not None:
            entry.update({"explained": c.explained, "delta_bic": c.delta_bic, "delta_ebic": c.delta_ebic,
                          "moved_from": c.moved_from})
        cands.append(entry)
    fe = base.evaluations + sum(c.fit.evaluations for c in ranked if c.fit is not None)
    return {
        "run_id": run_info.get("run_id"),
        "run_folder": run_info.get("run_folder"),
        "measured": settings["measured"],
        "settings": dict(settings),
        "decision": decision,
        "effect": effect,
        "error_before": e_before,
        "error_after": e_after,
        "per_sensor_error_before": s_before,
        "per_sensor_error_after": s_after,
        "noise_floor": before.noise_floor,
        "parameters_run": run_info.get("parameters"),
        "parameters_before": _params(base, library),
        "parameters_after": _params(final, library),
        "residual_before": before.to_dict(),
        "residual_after": after.to_dict(),
        "candidates": cands,
        "n_candidates": len(ranked),
        "residual_tables": {"before": "residual_before.parquet", "after": "residual_after.parquet"},
        "tables": {"screen": "step=screen/screen.parquet", "checks": "step=check/checks.parquet",
                   "candidates": "step=decide/candidates.parquet"},
        "fe_solves": int(fe),
    }
