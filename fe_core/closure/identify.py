"""How strongly the data single out each added effect: its kind's share of the evidence and its place's spread.

After a swap pass that changes nothing, every added effect has **rivals**: the full fits of the alternatives
checked in its place with the same other effects. Their extended BICs weigh the kinds (:func:`evidence`):
``w_k = exp(-EBIC_k / 2) / sum_j exp(-EBIC_j / 2)`` over the best location of each plausible kind, an
approximation of the posterior probability of the kind given the data (Schwarz; Kass & Raftery 1995), with the
extended BIC's ``2 ln L`` charging each kind for the ``L`` locations it was searched over. An effect whose kind
holds less than :data:`IDENTIFIED` of the weight is not identified: "a point mass or a stiffer patch, the data
cannot tell" is the honest verdict (``ambiguous``), not a finding. Nor is one whose location is not pinned down:
the effect moved (linearised) to every location of its kind gives the locations holding 95 % of the evidence
(:func:`location_spread`); spread over more than :data:`LOCATION_SHARE` of the structure, the node and the size
found are one of many that fit (a point mass of 0.064 kg 50 mm from a true one of 0.15 kg fits as well).

Effects of one additive kind (point masses; springs to ground along one axis) added within that same share of the
structure's size of one another are one effect between nodes (:func:`combined`): the model places them at nodes
only, so a mass between two nodes is found as two (held-out hd02: 0.145 and 0.095 kg 15 mm apart for one of 0.243
kg between them). Their sum at their value-weighted centre (the mass's first moment; the springs' resultant) is
what the data say.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .effects import Effect
from .fits import Fit
from .screening import Candidate, _relocation_fits

__all__ = ["Rival", "Combined", "evidence", "location_spread", "spread_mm", "located", "searched", "combined",
           "IDENTIFIED", "RIVAL_SHARE", "LOCATION_SHARE"]

#: Share of the evidence an effect's kind must hold among the kinds checked in its place to count as
#: identified: 0.95, i.e. ``2 ln B > 6`` against a single rival ("strong" on Kass & Raftery's scale).
IDENTIFIED = 0.95
#: Rivals listed per effect (those holding at least 1 % of the evidence, best first).
RIVAL_SHARE = 0.01
#: An effect is located when the locations of its kind holding 95 % of the evidence lie within this share
#: of the structure's size (the diagonal of the mesh's bounding box: 32 mm on the 641 mm benchmark, two
#: elements); a kind with several locations and no positions is located only when one location holds it.
LOCATION_SHARE = 0.05

@dataclass
class Rival:
    """An alternative checked in an added effect's place (the other effects refitted with it)."""

    effect: str
    location: str
    values: np.ndarray
    delta_ebic: float
    weight: float
    #: Too small to be an effect (the size rule): listed where it fits about as well, holding no evidence.
    negligible: bool = False


def evidence(incumbent: Candidate, rivals: Sequence[Candidate]) -> tuple[float, list[Rival]]:
    """The incumbent kind's share of ``exp(-EBIC / 2)`` among the plausible checked kinds, and the rivals.

    ``rivals`` are scored candidates (``ebic`` set) checked in the incumbent's
    place against the same other effects; the incumbent may be among them.
    Each kind counts once, with its best location. A rival implausible in size
    (``negligible``: it shifts no mode by the size rule's bar,
    :mod:`fe_core.closure.far.plausible`) is no rival, as it may not replace the
    effect in a swap either: it fits the model's own misfit, not another cause
    (held-out hd02: a patch shifting no mode by 0.4 % held all the evidence
    against a point mass of 0.145 kg). It is listed after the rivals, with no
    weight, where it would have held :data:`RIVAL_SHARE`.
    """
    best: dict[str, Candidate] = {}
    for c in list(rivals) + [incumbent]:
        if c.fit is None or c.ebic is None or ((c.implausible or c.negligible) and c is not incumbent):
            continue
        if c.effect not in best or c.ebic < best[c.effect].ebic:
            best[c.effect] = c
    if incumbent.effect in best and best[incumbent.effect].ebic > incumbent.ebic:
        best[incumbent.effect] = incumbent
    e0 = min(c.ebic for c in best.values())
    w = {k: float(np.exp(-(c.ebic - e0) / 2.0)) for k, c in best.items()}
    total = sum(w.values())
    share = {k: v / total for k, v in w.items()}
    listed = sorted((c for k, c in best.items() if k != incumbent.effect and share[k] >= RIVAL_SHARE),
                    key=lambda c: c.ebic)
    rivals_out = [Rival(c.effect, c.location, np.asarray(c.fit.values, float), float(c.ebic - incumbent.ebic),
                        share[c.effect]) for c in listed]
    small: dict[str, Candidate] = {}  # the negligible ones that would have held RIVAL_SHARE: listed, not weighed
    for c in rivals:
        if (c is not incumbent and c.negligible and not c.implausible and c.fit is not None and c.ebic is not None
                and c.effect not in best and c.ebic - e0 <= -2.0 * np.log(RIVAL_SHARE * total)
                and (c.effect not in small or c.ebic < small[c.effect].ebic)):
            small[c.effect] = c
    rivals_out += [Rival(c.effect, c.location, np.asarray(c.fit.values, float), float(c.ebic - incumbent.ebic), 0.0,
                         negligible=True) for c in sorted(small.values(), key=lambda c: c.ebic)]
    return share[incumbent.effect], rivals_out


def location_spread(model, freqs_hz, fit: Fit, index: int, share: float = IDENTIFIED) -> list[tuple[str, float]]:
    """The locations of one fitted effect's kind that hold ``share`` of the evidence, best first.

    The effect is moved, in the linearisation at the fitted point (alpha and
    the other effects refitted), to every location of its kind not taken by
    another effect of that kind; each location is weighed by
    ``exp(-N ln(RSS) / 2)`` (same parameters, same search: the extended BIC's
    differences), and the smallest set holding ``share`` of the weight is
    returned with the weights. A kind with one location gives itself.
    """
    a = fit.applied[index]
    if not searched(a.effect):
        return [(a.location, 1.0)]
    taken = {b.location for i, b in enumerate(fit.applied) if i != index and b.effect.kind == a.effect.kind}
    locations = [loc for loc in a.effect.locations() if loc not in taken]
    _, rss = _relocation_fits(model, freqs_hz, fit, a.effect, locations, index=index)
    n = fit.residual.size
    e = n * np.log(np.maximum(rss, 1e-300))
    w = np.exp(-(e - e.min()) / 2.0)
    w /= w.sum()
    order = np.argsort(-w)
    keep = order[: int(np.searchsorted(np.cumsum(w[order]), share)) + 1]
    return [(locations[k], float(w[k])) for k in keep]


def spread_mm(effect: Effect, location: str, spread: Sequence[tuple[str, float]]) -> float | None:
    """Largest distance, mm, from ``location`` to the locations of a spread (None without positions)."""
    here = effect.position(location)
    where = [effect.position(loc) for loc, _ in spread]
    if here is None or any(p is None for p in where):
        return None
    return float(1e3 * max((np.linalg.norm(p - here) for p in where), default=0.0))


def located(model, effect: Effect, location: str, spread: Sequence[tuple[str, float]]) -> bool:
    """The spread of an effect's location is small: ``location`` alone, or all within :data:`LOCATION_SHARE`
    of the structure's size of ``location``."""
    if all(loc == location for loc, _ in spread):
        return True
    far = spread_mm(effect, location, spread)
    size_m = getattr(model, "size_m", None)
    if far is None or size_m is None:
        return False
    return far <= LOCATION_SHARE * 1e3 * size_m


def searched(effect: Effect) -> bool:
    """One value at many locations: a kind whose place is searched (and can move)."""
    return effect.n_parameters == 1 and len(effect.locations()) > 1


@dataclass
class Combined:
    """Added effects of one additive kind close together, taken as one: their ``indices`` in the fit's effects,
    ``value`` the sum, ``position`` (m) the value-weighted centre, ``span_mm`` the largest distance between two."""

    effect: str
    indices: list[int]
    locations: list[str]
    value: float
    position: np.ndarray
    span_mm: float


def combined(model, applied: Sequence) -> list[Combined]:
    """The groups of two or more added effects (:class:`fe_core.closure.effects.Applied`) of one additive kind
    (``Effect.additive``: one value that adds, a place) linked by distances of at most :data:`LOCATION_SHARE` of
    the structure's size (``model.size_m``); none without positions or a size."""
    size_m = getattr(model, "size_m", None)
    if size_m is None:
        return []
    reach = LOCATION_SHARE * float(size_m)
    out = []
    kinds = {a.effect.kind for a in applied if getattr(a.effect, "additive", False)}
    for kind in sorted(kinds):
        where = {i: a.effect.position(a.location) for i, a in enumerate(applied) if a.effect.kind == kind}
        pos = {i: np.asarray(p, float) for i, p in where.items() if p is not None}
        idx = list(pos)
        groups: list[list[int]] = []
        for i in idx:  # single linkage
            near = [g for g in groups if any(np.linalg.norm(pos[i] - pos[j]) <= reach for j in g)]
            merged = [i] + [j for g in near for j in g]
            groups = [g for g in groups if g not in near] + [sorted(merged)]
        for g in groups:
            if len(g) < 2:
                continue
            v = np.array([float(applied[i].values[0]) for i in g])
            p = np.array([pos[i] for i in g])
            centre = (v @ p) / v.sum() if v.sum() > 0 else p.mean(axis=0)
            span = max(np.linalg.norm(p[a] - p[b]) for a in range(len(g)) for b in range(a + 1, len(g)))
            out.append(Combined(kind, g, [applied[i].location for i in g], float(v.sum()), centre, 1e3 * float(span)))
    return out
