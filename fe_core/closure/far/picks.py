"""The exact search's candidates as the closure's :class:`fe_core.closure.screening.Candidate`, to be checked on the
full FE model from where the search fitted them (alpha and the effect's value together)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..effects import Effect
from ..fits import ALPHA_BOUNDS, Fit
from ..screening import Candidate
from .search import Found, exact_search

__all__ = ["search_candidates", "pick_found", "CHECKED", "FACTOR"]

#: Candidates of the search checked in full: the best of each kind whose reduced sum of squares is within
#: :data:`FACTOR` of the best one's, at most :data:`CHECKED` of them, the best two always.
CHECKED, FACTOR = 4, 10.0


def pick_found(found: Sequence[Found], checked: int = CHECKED, factor: float = FACTOR) -> list[Found]:
    """The search's candidates worth a full check (see :data:`CHECKED`)."""
    if not found:
        return []
    ranked = sorted(found, key=lambda f: f.rss)
    best = ranked[0].rss
    picks = list(ranked[:2])
    kinds = {f.effect for f in picks}
    for f in ranked[2:]:
        if len(picks) >= checked:
            break
        if f.effect not in kinds and f.rss <= factor * max(best, 1e-300):
            picks.append(f)
            kinds.add(f.effect)
    return picks


def as_candidate(f: Found, base: Fit) -> Candidate:
    """A found candidate as the closure's: its value as the start size, its alpha as the start of the check."""
    explained = 1.0 - f.rss / base.rss if base.rss > 0 else 0.0
    return Candidate(effect=f.effect, location=f.location, n_locations=f.n_locations,
                     linear_values=np.asarray(f.values, float), linear_rss=float(f.rss), linear_explained=explained,
                     start_alpha=np.asarray(f.alpha, float))


def search_candidates(model, freqs_hz, amplitude, base: Fit, library: Sequence[Effect], *,
                      alpha_bounds=ALPHA_BOUNDS, checked: int = CHECKED) -> tuple[list[Candidate], dict]:
    """:func:`exact_search` from ``base`` (its alpha and effects) and the picks as candidates; with the search's
    record (its best candidates listed)."""
    found, record = exact_search(model, freqs_hz, amplitude, base.alpha, library, base.applied,
                                 alpha_bounds=alpha_bounds)
    picks = pick_found(found, checked)
    record["found"] = [{"effect": f.effect, "location": f.location, "values": [float(v) for v in f.values],
                        "alpha": [float(a) for a in f.alpha], "rss": f.rss, "scan": f.scan} for f in found[:12]]
    record["picked"] = [[f.effect, f.location] for f in picks]
    return [as_candidate(f, base) for f in picks], record
