"""The closure on modal residuals: effects the model lacks (a point mass, a grounded spring, a segment's
mass; :mod:`fe_core.closure.effects`) traced from what the modal update left.

1. **Screen** (linearised, every candidate effect x location at the updated point ``theta``): an effect
   value ``d`` moves the paired eigenvalues by ``d lambda = phi^T (dK - lambda dM) phi`` (mass-normalised
   ``phi``; ``dK``, ``dM`` the effect's terms at a unit value, :meth:`Effect.derivative`) and the shapes by
   Nelson's ``d phi`` at the test DOFs (:func:`fe_core.modal_update.nelson.eigen_derivatives_at`, one
   adjoint solve per mode for all candidates); through :meth:`ModalResidual.jacobian` these give the column ``j`` of the weighted residual.
   With ``r`` the residual and ``Q`` an orthonormal basis of the parameters' Jacobian (the parameters are
   refitted with the effect), the candidate explains ``||P r||^2 - min_{d in bounds} ||P (r + j d)||^2``,
   ``P = I - Q Q^T`` (``linear_drop``, in chi-square units).
2. **Check**: the best ``n_check`` candidates (and the best of another kind screened at least half as
   good, :func:`pick`) are fitted in full (parameters and the effect's value,
   trust-region least squares with exact Jacobians from ``[theta, linear value]``).
3. **Decide** (forward selection, the FRF closure's rule, :mod:`fe_core.closure.selection`): the residual is
   weighted by the measurement's standard deviations, so ``chi^2`` is the test: ``structured`` when
   ``P(chi^2_{n-k} > chi^2) < level``. While it is structured, the checked candidate that lowers the extended
   BIC ``chi^2 + k ln n + 2 sum_j ln L_j`` most (``k`` parameters and effect values, ``L_j`` the candidate
   locations of each effect: choosing the best of many nodes is a fit too) is added if its fit (and every
   effect's value in it) does not end on a plausibility bound; the next round screens and checks with the
   effects so far in the model (:class:`ExtendedModalResidual`), each check a joint refit of the factors, the
   effects so far and the new one. It stops at the noise, when nothing lowers the extended BIC, or at
   ``max_effects``. No swaps (the FRF closure's replacement passes) yet. The verdict: ``noise`` (the
   residual after the update is noise: no effect named), ``explained`` (effects added, noise after them),
   ``partly explained`` (effects added, structure remains), ``not explained`` (structure, and no candidate
   of the library lowers the extended BIC).

Every FE run (screens and checks) goes to the residual's ``history`` with its stage
(``closure-<round>: screen`` or ``closure-<round>: <effect> at <location>``), which the flow writes to
``modal_runs.jsonl``. One-parameter effects only (all of the default library's).
"""

from __future__ import annotations

import numpy as np

from .fit import fit_modes
from .nelson import eigen_derivatives_at, parameter_matrices
from .residual import ModalResidual

__all__ = ["modal_closure", "screen_effects", "ExtendedModalResidual", "LEVEL"]

#: Significance level of the chi-square test of "structure".
LEVEL = 0.01
#: Candidates per batch of the derivative solves (bounds the memory of the shape derivatives).
CHUNK = 600


def _chi2_test(chi2: float, n: int, k: int) -> dict:
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    dof = max(n - k, 1)
    p = float(stats.chi2.sf(chi2, dof))
    return {"chi2": float(chi2), "dof": dof, "p_value": p, "structured": p < LEVEL}


def _unit_terms(effect, alpha, location):
    t = effect.derivative(alpha, location, 0)
    return t.stiffness, t.mass


def screen_effects(residual: ModalResidual, theta, library) -> tuple[list[dict], dict]:
    """Linearised screen of every (effect, location) at ``theta`` (module docstring, step 1).

    Returns the candidates (dicts, best drop first) and the base: ``r``, ``chi2``, ``n``, ``k``.
    """
    theta = np.asarray(theta, float)
    out = residual.evaluate(theta)
    r, J, pairing = out["r"], out["J"], out["pairing"]
    key = tuple(theta.tolist())
    if key not in residual._modes:  # the evaluation was cached; its modes were not kept
        residual._modes = {key: residual.modes_at(theta)}
    freqs, psi, vecs, lam, K, M = residual._modes[key]
    q, _ = np.linalg.qr(J)
    r_perp = r - q @ (q.T @ r)
    rss0 = float(r_perp @ r_perp)
    alpha, _ = residual.model.factors(theta[:residual.model.n_parameters])
    candidates, factors = [], {}
    for effect in library:
        if effect.n_parameters != 1:
            continue
        locations = effect.locations()
        for start in range(0, len(locations), CHUNK):
            chunk = locations[start:start + CHUNK]
            dmats = [_unit_terms(effect, alpha, loc) for loc in chunk]
            dlam, dpsi = eigen_derivatives_at(K, M, lam, vecs, dmats, residual.L, pairing.model, factors)
            scale = np.array([effect.scale_at(loc)[0] for loc in chunk])
            cols = residual.jacobian(freqs, psi, pairing, dlam, dpsi, at_test=True) * scale[None, :]  # per scale unit
            cols = cols - q @ (q.T @ cols)
            jj = np.einsum("nl,nl->l", cols, cols)
            with np.errstate(invalid="ignore", divide="ignore"):
                d = np.where(jj > 0, -(cols.T @ r_perp) / jj, 0.0)
            bounds = [effect.bounds_at(loc) for loc in chunk]
            lo = np.array([b[0][0] for b in bounds]) / scale
            hi = np.array([b[1][0] for b in bounds]) / scale
            d = np.clip(d, lo, hi)
            res = r_perp[:, None] + cols * d[None, :]
            rss = np.einsum("nl,nl->l", res, res)
            for k, loc in enumerate(chunk):
                candidates.append({"effect": effect.kind, "location": loc, "n_locations": len(locations),
                                   "value": float(d[k] * scale[k]), "unit": effect.units[0],
                                   "linear_drop": float(rss0 - rss[k]), "position_m": _position(effect, loc)})
    candidates.sort(key=lambda c: -c["linear_drop"])
    return candidates, {"r": r, "chi2": float(r @ r), "n": int(r.size), "k": int(J.shape[1]), "rss_perp": rss0}


def _position(effect, location):
    p = effect.position(location)
    return None if p is None else [float(v) for v in p]


class ExtendedModalResidual(ModalResidual):
    """The modal residual of the model with effects added: parameters ``[theta, d_1 / scale_1, ...]``, one
    value per (effect, location) of ``added``. Its FE runs go to ``base``'s history (one log per run)."""

    def __init__(self, base: ModalResidual, added, label: str = "closure"):
        super().__init__(base.model, base.L, base.f_test, base.u_test, base.sigma_f, base.sigma_s, base.n_model,
                         base.threshold, base.names)
        self.active = base.active.copy()
        self.history = base.history  # one log of every FE run of the run (modal_runs.jsonl)
        self.label = label
        self.n_base = base.model.n_parameters
        alpha0 = np.zeros(base.model.n_segments)
        self.terms, self.scales = [], []
        for effect, location in added:
            scale = float(effect.scale_at(location)[0])
            dK, dM = _unit_terms(effect, alpha0, location)
            self.terms.append((None if dK is None else dK * scale, None if dM is None else dM * scale))
            self.scales.append(scale)
        self.scale = self.scales[-1] if self.scales else 1.0
        self.dmats = parameter_matrices(base.model) + list(self.terms)

    def matrices(self, theta):
        theta = np.asarray(theta, float)
        K, M = super().matrices(theta[:self.n_base])
        for v, (dK, dM) in zip(theta[self.n_base:], self.terms):
            K = K if dK is None else K + float(v) * dK
            M = M if dM is None else M + float(v) * dM
        return K, M


def check_candidate(residual: ModalResidual, theta, lower, upper, candidate: dict, effect, added=(),
                    step: int = 1) -> dict:
    """Full joint fit of the parameters, the effects ``added`` so far (``theta``, ``lower``, ``upper`` hold
    their scaled values after the parameters) and one candidate's value (module docstring, step 2)."""
    added = list(added)
    ext = ExtendedModalResidual(residual, added + [(effect, candidate["location"])],
                                f"closure-{step}: {effect.kind} at {candidate['location']}")
    runs0 = len(residual.history)
    lo, hi = effect.bounds_at(candidate["location"])
    lo_e, hi_e = float(lo[0]) / ext.scale, min(float(hi[0]) / ext.scale, 1e6)
    x0 = np.append(np.asarray(theta, float), np.clip(candidate["value"] / ext.scale, lo_e, hi_e))
    fit = fit_modes(ext, np.append(lower, lo_e), np.append(upper, hi_e), n_starts=1, x0=x0, stated=True)
    n_base = residual.model.n_parameters
    values = fit.theta[n_base:] * np.array(ext.scales)
    sds = fit.sd[n_base:] * np.array(ext.scales)
    at_bound = []
    for (e, loc), v in zip(added + [(effect, candidate["location"])], values):
        upper_e = float(e.bounds_at(loc)[1][0])
        at_bound.append(bool(np.isfinite(upper_e) and v >= upper_e * (1 - 1e-3)))
    return {**candidate, "value": float(values[-1]), "theta": fit.theta[:n_base].tolist(),
            "theta_full": fit.theta.tolist(), "values": values.tolist(), "sds": sds.tolist(),
            "chi2": float(fit.chi2), "sd": float(sds[-1]), "fe_runs": len(residual.history) - runs0,
            "implausible": any(at_bound)}


def pick(screened: list[dict], n_check: int) -> list[dict]:
    """The candidates fitted in full: the ``n_check`` best screened, and the best of each other kind whose
    linearised drop is at least half the best's (so that a rival kind is checked, not only neighbours)."""
    chosen = list(screened[:n_check])
    if not screened:
        return chosen
    kinds = {c["effect"] for c in chosen}
    for c in screened:
        if c["effect"] not in kinds and c["linear_drop"] >= 0.5 * screened[0]["linear_drop"] > 0:
            chosen.append(c)
            kinds.add(c["effect"])
    return chosen


def modal_closure(residual: ModalResidual, theta, lower, upper, stated: bool = True,
                  effects=("point_mass", "grounded_spring", "segment_mass"), n_check: int = 2,
                  n_report: int = 10, max_effects: int = 3) -> dict:
    """Forward selection (module docstring): screen, check, add while the extended BIC improves and the
    residual is structured; a JSON-ready dict with the verdict, the effects added (``added``, their values
    from the last joint fit; ``chosen`` the first), the chi-square tests before and after, every round's
    candidates and the FE runs."""
    from ..closure.effects import build_library

    library = build_library(residual.model, list(effects))
    by_kind = {e.kind: e for e in library}
    runs0 = len(residual.history)
    theta = np.asarray(theta, float)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    current, theta_full, lo_full, hi_full = residual, theta, lower, upper
    steps, rounds, table = [], [], []
    before = after = None
    n = k = 0
    ebic = 0.0
    while len(steps) < max_effects and (after is None or after["structured"]):
        current.label = f"closure-{len(steps) + 1}: screen"
        screened, base = screen_effects(current, theta_full, library)
        if before is None:
            n, k = base["n"], base["k"]
            before = after = _chi2_test(base["chi2"], n, k)
            ebic = base["chi2"] + k * np.log(n)
        if not after["structured"]:
            break
        checked = []
        for c in pick(screened, n_check):
            c = check_candidate(residual, theta_full, lo_full, hi_full, c, by_kind[c["effect"]],
                                [(by_kind[s["effect"]], s["location"]) for s in steps], len(steps) + 1)
            locations = sum(np.log(s["n_locations"]) for s in steps) + np.log(c["n_locations"])
            c["delta_bic"] = float(c["chi2"] + (k + 1) * np.log(n) + 2 * locations - ebic)
            c["step"] = len(steps) + 1
            checked.append(c)
        plausible = [c for c in checked if not c["implausible"] and c["delta_bic"] < 0]
        keys = {(c["effect"], c["location"]) for c in checked}
        table += checked + [dict(c, chi2=None, delta_bic=None, step=len(steps) + 1) for c in screened
                            if (c["effect"], c["location"]) not in keys][:max(n_report - len(checked), 0)]
        rounds.append({"step": len(steps) + 1, "chi2_before": base["chi2"],
                       "checked": [{x: c[x] for x in ("effect", "location", "value", "chi2", "delta_bic",
                                                       "implausible", "fe_runs")} for c in checked]})
        if not plausible:
            break
        chosen = min(plausible, key=lambda c: c["delta_bic"])
        steps.append(chosen)
        for s, v, d in zip(steps, chosen["values"], chosen["sds"]):  # the joint refit's values
            s["value"], s["sd"] = float(v), float(d)
        k += 1
        ebic += chosen["delta_bic"]
        after = _chi2_test(chosen["chi2"], n, k)
        theta_full = np.asarray(chosen["theta_full"], float)
        lo_e, hi_e = (float(b[0]) / float(by_kind[chosen["effect"]].scale_at(chosen["location"])[0])
                      for b in by_kind[chosen["effect"]].bounds_at(chosen["location"]))
        lo_full, hi_full = np.append(lo_full, lo_e), np.append(hi_full, min(hi_e, 1e6))
        current = ExtendedModalResidual(residual, [(by_kind[s["effect"]], s["location"]) for s in steps])
    residual.label = "fit"
    if not before["structured"]:
        verdict = "noise"
    elif not steps:
        verdict = "not explained"
    else:
        verdict = "partly explained" if after["structured"] else "explained"
    added = [{x: s[x] for x in ("effect", "location", "value", "unit", "sd", "position_m", "n_locations")}
             for s in steps]
    return {"verdict": verdict, "effects": list(effects), "before": before, "after": after if steps else None,
            "chosen": steps[0] if steps else None, "added": added, "rounds": rounds,
            "theta": (theta_full[:theta.size] if steps else theta).tolist(),
            "candidates": table, "n_screened": len(screened),
            "fe_runs": len(residual.history) - runs0,
            "uncertainties": "stated" if stated else "the default uncertainties (sigma_f 0.002, sigma_s 0.02) "
                             "taken as stated for the test", "level": LEVEL}
