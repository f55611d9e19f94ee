"""What the update hands its closure (``flows.update --close-loop``, or ``flows.diagnose`` of a finished run): the
effects its evidence evaluated exactly, as candidates to check (:func:`evidence_picks`), and whether its evidence
weighed the basins already (then a large model's baseline makes no restarts)."""

from __future__ import annotations

import json

import numpy as np

from tasks.closure.store import _logger
from tasks.fe_runs import is_large

__all__ = ["evidence_found", "evidence_picks", "restarts"]


def evidence_found(store, library) -> list:
    """The effects the update's evidence evaluated exactly (``summary.json``'s ``evidence.screens`` of the run whose
    closure this is), as found candidates with the alpha fitted with them; none without them."""
    from fe_core.closure.far.search import Found

    screens = _run_evidence(store).get("screens") or []
    out = []
    for sc in screens:
        if sc.get("exact") and sc.get("effect") in library and sc.get("effect_alpha"):
            out.append(Found(sc["effect"], sc["location"], np.asarray(sc["values"], float),
                             np.asarray(sc["effect_alpha"], float), float(sc["rss_effect"]), float(sc["rss_effect"]),
                             len(library[sc["effect"]].locations())))
    return out


def evidence_picks(store, model, library, picks: list, found: list) -> list:
    """``picks`` (the exact search's, from its ``found``) and the evidence's exact finds at other places
    (:func:`evidence_found`). For a large model (:func:`tasks.fe_runs.is_large`) an evidence find joins only if its sum
    of squares is within :data:`fe_core.closure.far.picks.FACTOR` of the search's best, the rule the search's own
    further finds are picked by: the search scanned every place exactly from the closure's baseline, and a check
    started a factor of ten worse walks to where the search already is, taking minutes per FE solve (500k panel:
    the evidence's node 125810, 28.8 against the search's 1.26, checked in 12 solves and 17 min and ended at the
    search's node 66094; 150k: node 40610, 17.9 against 0.18, 121 s, ended at the search's 24957). Below that size
    a check takes seconds and every evidence find is checked, as before."""
    from fe_core.closure.far.picks import FACTOR

    best = min((f.rss for f in found), default=float("inf"))
    out = list(picks)
    for e in evidence_found(store, library):
        if any((e.effect, e.location) == (f.effect, f.location) for f in out):
            continue
        if is_large(model) and e.rss > FACTOR * best:
            _logger().info("closure: the evidence's %s at %s (sum of squares %.4g) not checked: more than %g times "
                           "the exact search's best (%.4g)", e.effect, e.location, e.rss, FACTOR, best)
            continue
        out.append(e)
    return out


def _run_evidence(store) -> dict:
    """``summary.json``'s ``evidence`` of the run whose closure this is ({} without one)."""
    try:
        return json.loads((store.root.parent / "summary.json").read_text()).get("evidence") or {}
    except (OSError, ValueError, AttributeError):
        return {}


def restarts(store, model, settings: dict) -> int:
    """The baseline's Sobol restarts: none for a large model (:func:`tasks.fe_runs.is_large`) whose update handed
    over to the closure on its evidence (an effect evaluated exactly that leaves at most a quarter of the best
    basin's sum of squares): the weighing asked what the restarts ask, and at size they cost FE runs of minutes for
    nothing (500k: 14.4 min for 25.2 -> 24.3 % rms; 150k: 3.2 min for 24.9 -> 24.2 %)."""
    ev = _run_evidence(store)
    if settings["restarts"] and is_large(model) and ev.get("choice") == "closure" and any(
            sc.get("exact") for sc in ev.get("screens") or []):
        _logger().info("closure baseline: no restarts (the update's evidence weighed the basins already: %s)",
                       ev.get("reason", ""))
        return 0
    return settings["restarts"]
