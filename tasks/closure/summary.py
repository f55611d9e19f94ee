"""What a closure reports: ``closure.json`` (the decision, the effects with their evidence and rivals,
errors and parameters before and after, the best candidates) and the ranked candidates' table."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from fe_core.closure import fits, screening
from fe_core.closure.decisions import bound_hit
from fe_core.closure.identify import IDENTIFIED, combined, spread_mm
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
            "start": fit.start if fit is not None else "",
            "at_bound": bool(fit is not None and c.implausible),
        })
    return pd.DataFrame(rows)


def _effect_entry(c: screening.Candidate, library: dict, values=None) -> dict:
    eff = library[c.effect]
    v = c.fit.values if values is None else values
    return {"type": c.effect, "location": c.location,
            "value": float(v[0]) if eff.n_parameters == 1 else dict(zip(eff.parameters, map(float, v))),
            "parameter": eff.parameters[0], "unit": _unit(eff, c.location), "details": eff.describe(c.location),
            # The plausibility bound the fit ends on (None: inside the box) and the joint fit's winning start.
            "at_bound": bound_hit(eff, c.location, v), "start": getattr(c.fit, "start", "") or None}


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
                 "moved_from": list(c.moved_from), "status": effect_status(verdict),
                 "evidence": w, "located": bool(at), "identified": bool(w >= IDENTIFIED and at),
                 "rivals": [{"type": r.effect, "location": r.location, "value": float(r.values[0]),
                             "unit": _unit(library[r.effect], r.location), "delta_ebic": r.delta_ebic,
                             "evidence": r.weight, "negligible": r.negligible} for r in rv],
                 "locations_95": len(sp), "spread_mm": spread_mm(library[c.effect], c.location, sp) if sp else None,
                 "locations": [{"location": loc, "evidence": wl} for loc, wl in sp[:LOCATIONS_IN_JSON]]}
        effects.append(entry)
    together = []
    model = next(iter(library.values())).model if library else None  # every effect of the library is built on it
    for g in combined(model, final.applied if steps else []):  # found as two beside each other: one between nodes
        eff = library[g.effect]
        together.append({"type": g.effect, "locations": g.locations, "steps": [i + 1 for i in g.indices],
                         "value": g.value, "unit": _unit(eff, g.locations[0]),
                         "position_m": [float(x) for x in g.position], "span_mm": g.span_mm})
        for i in g.indices:
            effects[i]["combined"] = len(together) - 1
    return {"verdict": verdict, "effects": effects, "combined": together,
            "implausible": [{**_effect_entry(c, library), "explained": c.explained} for c in implausible],
            "swaps": list(sel.swaps) if sel is not None else [], "moves": list(sel.moves) if sel is not None else []}


#: What an added effect is under each verdict, as closure.json's ``status`` and the printout say it.
STATUSES = {"finding": "added", "ambiguous": "added, not a finding (the closure is ambiguous)",
            "candidate": "candidate (structure remains, not a finding)"}


def effect_status(verdict: str) -> str:
    """``finding`` (verdict ``explained``: the data explain the residual with the effects and single each out),
    ``ambiguous`` (they explain it, but a rival or another place does about as well: none is a finding) or
    ``candidate`` (structure remains: not a finding). Whether the evidence singles out one effect among the
    rivals checked in its place is its own field, ``identified`` (with ``located``: its place is pinned down)."""
    return {"explained": "finding", "ambiguous": "ambiguous"}.get(verdict, "candidate")


def decision_text(verdict: str, effects: list[dict], before, analysis_after, moves=(), combined_groups=()) -> str:
    """The closure's headline, from the final effects (their places after every move and swap); ``moves`` says
    whether the backward check dropped effects that did not carry over across the band; ``combined_groups``
    (closure.json's ``combined``) names effects found beside each other that are one between nodes."""
    if effects:
        added = "; ".join(f"{STATUSES[e['status']].split(' (')[0]} {e['type']} at {e['location']}"
                          + (f" (moved from {', '.join(e['moved_from'])})" if e.get("moved_from") else "")
                          for e in effects)
        for g in combined_groups or ():
            added += (f" ({' and '.join(g['locations'])}, {g['span_mm']:.0f} mm apart, are one {g['type']} of "
                      f"{g['value']:.4g} {g['unit']} between them, at ({', '.join(f'{x:.3f}' for x in g['position_m'])})"
                      " m)")
        return (f"{added}: the residual before is structure (chi-square p = {before.p_chi2:.3g}); after: "
                f"{'noise' if not analysis_after.structured else 'structure remains'} "
                f"(p = {analysis_after.p_chi2:.3g}); verdict {verdict}")
    if not before.structured:
        return f"no effect: the residual is noise (chi-square p = {before.p_chi2:.3g} >= {before.significance})"
    dropped = [m.split(" dropped:")[0] for m in moves if "does not carry over" in m]
    if dropped:
        return (f"no effect: {'; '.join(dropped)} did not carry over from one half of the lines to the other (the "
                "model's own error where fitted) and was dropped")
    return "no effect: no checked candidate lowers the extended BIC"


def _unit(effect, location) -> str:
    if effect.kind == "damping":
        return effect.describe(location)["unit"]
    return effect.units[0]


def _errors(fit, u, sensors):
    rel = fit.relative(u)
    return overall_error(rel), {f"sensor_{int(s)}": float(v) for s, v in zip(sensors, per_sensor_error(rel))}


def effect_parameter(kind: str, location: str, parameter: str) -> str:
    """The one name of an effect's parameter in closure.json, its intervals and the printout:
    ``<kind>@<location>.<parameter>``, e.g. ``point_mass@node 412.mass``."""
    return f"{kind}@{location}.{parameter}"


def _params(fit, library) -> dict:
    out = {f"alpha_{i + 1}": float(v) for i, v in enumerate(fit.alpha)}
    for a in fit.applied:  # the effects in the order added
        out.update({effect_parameter(a.effect.kind, a.location, n): float(v)
                    for n, v in zip(a.effect.parameters, a.values)})
    return out


def _closure_json(store, settings, run_info, base, final, before, after, ranked, library, u, sensors,
                  freqs, verdict_part: dict, error_at_run: float) -> dict:
    e_before, s_before = _errors(base, u, sensors)
    e_after, s_after = _errors(final, u, sensors)
    effects = verdict_part["effects"]
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
    known = after if settings["noise"] is None else before  # the configured noise, or the level of what is left
    return {
        "run_id": run_info.get("run_id"),
        "run_folder": run_info.get("run_folder"),
        "measured": settings["measured"],
        "settings": dict(settings),
        **verdict_part,
        "decision": decision_text(verdict_part["verdict"], effects, before, after, verdict_part.get("moves", ()),
                                  verdict_part.get("combined", ())),
        "effect": dict(effects[0]) if effects else None,  # the first effect added, as closure.json's effects[0]
        "error_metric": (f"Eq. (6b) of the relative amplitude residual over the closure's {u.size} values (the lines "
                         "where every channel is kept)"),
        "error_run": run_info.get("overall_error"),
        "error_run_metric": run_info.get("error_metric"),
        "error_at_run_parameters": error_at_run,
        "error_before": e_before,
        "error_after": e_after,
        "per_sensor_error_before": s_before,
        "per_sensor_error_after": s_after,
        "noise_floor": known.noise_floor if known.noise_known else None,
        "noise_floor_source": (known.sigma_source if known.noise_known else
                               "unknown: no noise configured, and the level estimated from the residual after the "
                               "closure is an upper bound (that residual is structure)"),
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
