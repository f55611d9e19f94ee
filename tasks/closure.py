"""Prefect tasks of the closure (``flows.diagnose``): residual, screening, checks, decision.

Everything goes under ``<run folder>/closure/`` (or another name), one
sub-folder per step with Parquet tables written atomically and a
``_step.json`` record of their SHA-256, as in :mod:`tasks.runstore`::

    closure/settings.json
    closure/step=baseline/baseline.parquet, residual_before.parquet
    closure/step=screen/screen.parquet
    closure/step=check/check=000.parquet ...     one per candidate, as it finishes
    closure/step=check/checks.parquet
    closure/step=decide/candidates.parquet, residual_after.parquet
    closure/residual_before.parquet, residual_after.parquet   (frequency_hz, sensor, residual)
    closure/closure.json, closure/residuals.png

A finished step is read back, not recomputed; a killed check stage keeps the
candidates already fitted. Each task wraps plain calls of :mod:`fe_core.closure.fits`,
:mod:`fe_core.closure.screening` and :mod:`fe_core.closure.decisions`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from joblib import Parallel, delayed
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.closure import decisions, fits, screening
from fe_core.closure.effects import Applied, build_library, extended_frf, registered_effects
from fe_core.closure.selection import IDENTIFIED, forward_select, spread_mm
from fe_core.inference.residual import analyse_residual, log_residual, overall_error, per_sensor_error
from tasks.runstore import atomic_write_bytes, atomic_write_json
from tasks.stages import load_model

__all__ = [
    "ClosureStore",
    "ClosureSettings",
    "baseline_task",
    "screen_task",
    "check_task",
    "decide_task",
    "residual_table",
    "effect_library",
]

log = logging.getLogger(__name__)
STEP_RECORD = "_step.json"
#: Candidates listed in closure.json (all of them are in candidates.parquet).
CANDIDATES_IN_JSON = 25
#: Locations of an added effect's kind listed with their evidence (of those holding 95 % of it).
LOCATIONS_IN_JSON = 10


def _logger():
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:
        return log


# -- settings -------------------------------------------------------------------------------------------
class ClosureSettings(dict):
    """Settings of one closure (a plain dict, stored in ``settings.json``).

    Keys: ``model``, ``measured``, ``alpha_start`` (list), ``noise`` (float or
    None = estimated), ``significance``, ``per_type``, ``max_moves``,
    ``restarts``, ``seed``, ``effects`` (list of registered names or None),
    ``alpha_bounds`` (pair), ``n_jobs``, ``max_effects`` (forward selection).
    """

    DEFAULTS = dict(noise=None, significance=0.01, per_type=1, max_moves=6, restarts=8, seed=0, effects=None,
                    alpha_bounds=list(fits.ALPHA_BOUNDS), n_jobs=1, check_noise=False,
                    max_effects=3)

    @classmethod
    def make(cls, **kwargs) -> "ClosureSettings":
        out = cls(cls.DEFAULTS)
        out.update({k: v for k, v in kwargs.items() if v is not None or k not in cls.DEFAULTS})
        return out


# -- the folder -----------------------------------------------------------------------------------------
def _parquet_bytes(df: pd.DataFrame) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(df, preserve_index=False), sink)
    return sink.getvalue().to_pybytes()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class ClosureStore:
    """One closure's folder: steps of Parquet tables with checksummed records."""

    def __init__(self, root: Path | str):
        self.root = Path(root)

    def step_dir(self, step: str) -> Path:
        return self.root / f"step={step}"

    def path(self, step: str, name: str) -> Path:
        return self.step_dir(step) / f"{name}.parquet"

    def write_table(self, step: str, name: str, df: pd.DataFrame) -> Path:
        path = self.path(step, name)
        atomic_write_bytes(path, _parquet_bytes(df))
        return path

    def read_table(self, step: str, name: str | None = None) -> pd.DataFrame:
        return pd.read_parquet(self.path(step, name or step))

    def finish(self, step: str, names: list[str], info: dict | None = None) -> None:
        files = {n: _sha256(self.path(step, n)) for n in names}
        atomic_write_json(self.step_dir(step) / STEP_RECORD,
                          {"files": files, "finished_unix": time.time(), "info": info or {}})

    def is_finished(self, step: str) -> bool:
        record = self.step_dir(step) / STEP_RECORD
        if not record.exists():
            return False
        try:
            files = json.loads(record.read_text()).get("files", {})
        except (OSError, json.JSONDecodeError):
            return False
        return all(self.path(step, n).exists() and _sha256(self.path(step, n)) == d for n, d in files.items())

    def info(self, step: str) -> dict:
        return json.loads((self.step_dir(step) / STEP_RECORD).read_text()).get("info", {})

    def write_settings(self, settings: dict) -> None:
        path = self.root / "settings.json"
        if path.exists():
            old = json.loads(path.read_text())
            changed = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k) and k != "n_jobs")
            if changed:
                raise ValueError(f"{path}: this closure was started with other settings ({', '.join(changed)}); "
                                 f"use the same settings to resume, or another --name")
        atomic_write_json(path, settings)


def _done(store: ClosureStore, step: str) -> bool:
    if store.is_finished(step):
        _logger().info("closure step %s: finished earlier, read back", step)
        return True
    return False


# -- conversions ------------------------------------------------------------------------------------------
def residual_table(freqs: np.ndarray, sensors: np.ndarray, relative: np.ndarray, logres: np.ndarray) -> pd.DataFrame:
    """Long table (frequency_hz, sensor, residual, log_residual), frequency-major; residual is Eq. 5's."""
    p, n = relative.shape
    return pd.DataFrame({"frequency_hz": np.repeat(np.asarray(freqs, float), n),
                         "sensor": np.tile(np.asarray(sensors, np.int64), p),
                         "residual": relative.ravel(), "log_residual": logres.ravel()})


def _fit_from_parameters(model, library, freqs, u, alpha, effect, location, values, evaluations=0,
                         seconds=0.0, message="") -> fits.Fit:
    """Rebuild a fit from stored parameters with one FRF evaluation."""
    applied = [] if effect is None else [Applied(library[effect], location, np.asarray(values, float))]
    amp = np.abs(extended_frf(model, alpha, freqs, applied))
    return fits.Fit(alpha=np.asarray(alpha, float), effect=effect, location=location,
                    values=np.asarray(values, float), model_amplitude=amp, residual=log_residual(amp, u),
                    evaluations=int(evaluations), seconds=float(seconds), message=message,
                    added=applied[0] if applied else None)


def _library(model, settings) -> dict:
    return _cached_library(model, settings.get("effects"))


def effect_library(model_name: str, effects=None) -> dict:
    """The effect library of a model by name or model-file path (``ValueError`` for an effect that does
    not apply to it), built once per process."""
    return _cached_library(load_model(model_name), effects)


def _cached_library(model, effects) -> dict:
    """The effect library by kind, built once per model and effect list in a process (the screen,
    every check and the decision of a closure use the same; 320 patches take a second to build)."""
    cache = model.__dict__.setdefault("_closure_libraries", {})
    key = (tuple(registered_effects()), None if effects is None else tuple(effects))
    if key not in cache:
        cache[key] = {e.kind: e for e in build_library(model, effects)}
    return cache[key]


def _param_table(fit: fits.Fit, library: dict) -> pd.DataFrame:
    names = [f"alpha_{i + 1}" for i in range(fit.alpha.size)]
    values = list(map(float, fit.alpha))
    if fit.effect is not None:
        names += list(library[fit.effect].parameters)
        values += list(map(float, fit.values))
    return pd.DataFrame({"name": names, "value": values})


# -- tasks ---------------------------------------------------------------------------------------------
@task(name="closure-baseline", cache_policy=NO_CACHE)
def baseline_task(root: str, settings: dict, freqs: np.ndarray, sensors: np.ndarray, u: np.ndarray) -> dict:
    """Alpha-only least squares from the run's parameters; residual and its analysis."""
    store = ClosureStore(root)
    if not _done(store, "baseline"):
        model = load_model(settings["model"])
        fit, analysis = fits.baseline(model, freqs, u, settings["alpha_start"], settings["noise"],
                                      settings["significance"], settings["restarts"], settings["seed"],
                                      tuple(settings["alpha_bounds"]))
        store.write_table("baseline", "baseline", _param_table(fit, {}))
        store.write_table("baseline", "residual_before",
                          residual_table(freqs, sensors, fit.relative(u), fit.residual))
        store.finish("baseline", ["baseline", "residual_before"],
                     {"analysis": analysis.to_dict(), "evaluations": fit.evaluations, "seconds": fit.seconds,
                      "message": fit.message})
        _logger().info("closure baseline: %s", analysis.summary())
    return store.info("baseline")


def _baseline_fit(store, model, freqs, u) -> fits.Fit:
    df = store.read_table("baseline")
    info = store.info("baseline")
    alpha = df.loc[df["name"].str.startswith("alpha_"), "value"].to_numpy()
    return _fit_from_parameters(model, {}, freqs, u, alpha, None, None, np.zeros(0), info["evaluations"],
                                info["seconds"], info["message"])


@task(name="closure-screen", cache_policy=NO_CACHE)
def screen_task(root: str, settings: dict, freqs: np.ndarray, u: np.ndarray) -> dict:
    """Linearised explained share of every candidate effect at the baseline."""
    store = ClosureStore(root)
    if not _done(store, "screen"):
        t0 = time.perf_counter()
        model = load_model(settings["model"])
        library = _library(model, settings)
        base = _baseline_fit(store, model, freqs, u)
        screened = screening.screen(model, freqs, base, list(library.values()))
        df = pd.DataFrame({
            "effect": [c.effect for c in screened],
            "location": [c.location for c in screened],
            "n_locations": [c.n_locations for c in screened],
            "linear_value": [float(c.linear_values[0]) for c in screened],
            "linear_values": [json.dumps(list(map(float, c.linear_values))) for c in screened],
            "linear_rss": [c.linear_rss for c in screened],
            "linear_explained": [c.linear_explained for c in screened],
            "linear_delta_bic": [c.linear_delta_bic for c in screened],
            "linear_delta_ebic": [c.linear_delta_ebic for c in screened],
        })
        store.write_table("screen", "screen", df)
        store.finish("screen", ["screen"], {"candidates": len(df), "seconds": time.perf_counter() - t0})
    return store.info("screen")


def _screened(store) -> list[screening.Candidate]:
    df = store.read_table("screen")
    return [screening.Candidate(effect=r.effect, location=r.location, n_locations=int(r.n_locations),
                           linear_values=np.array(json.loads(r.linear_values)), linear_rss=float(r.linear_rss),
                           linear_explained=float(r.linear_explained), linear_delta_bic=float(r.linear_delta_bic),
                           linear_delta_ebic=float(r.linear_delta_ebic))
            for r in df.itertuples(index=False)]


def check_candidate(model_name: str, effects, kind: str, location: str, linear_values, base_alpha, freqs, u,
                    max_moves: int, alpha_bounds) -> dict:
    """One full FE check (runs in a worker process); returns a flat record."""
    model = load_model(model_name)
    library = _cached_library(model, effects)
    cand = screening.Candidate(effect=kind, location=location, n_locations=len(library[kind].locations()),
                          linear_values=np.asarray(linear_values, float), linear_rss=0.0, linear_explained=0.0)
    base = fits.Fit(alpha=np.asarray(base_alpha, float), effect=None, location=None, values=np.zeros(0),
                    model_amplitude=None, residual=np.full(np.shape(u), np.inf), evaluations=0)
    # The base residual is only compared against (a fit worse than it restarts from zero):
    base.residual = log_residual(np.abs(extended_frf(model, base.alpha, freqs)), u)
    screening.check(model, freqs, u, base, library[kind], cand, max_moves, tuple(alpha_bounds))
    f = cand.fit
    return {"effect": kind, "screened_location": location, "location": f.location,
            "moved_from": json.dumps(cand.moved_from), "values": json.dumps(list(map(float, f.values))),
            "alpha": json.dumps(list(map(float, f.alpha))), "rss": f.rss, "evaluations": f.evaluations,
            "seconds": f.seconds, "message": f.message}


@task(name="closure-check", cache_policy=NO_CACHE)
def check_task(root: str, settings: dict, freqs: np.ndarray, u: np.ndarray) -> dict:
    """Full FE least squares of the best-screened candidates, in parallel, each stored as it finishes."""
    store = ClosureStore(root)
    logger = _logger()
    if not _done(store, "check"):
        analysis = store.info("baseline")["analysis"]
        screened = _screened(store)
        picked = screening.pick_for_check(screened, settings["per_type"])
        if not (analysis["structured"] or settings.get("check_noise")):
            logger.info("closure: the residual is noise (chi-square p = %.3g); no candidate is checked",
                        analysis["p_chi2"])
            picked = []
        model = load_model(settings["model"])
        base = _baseline_fit(store, model, freqs, u)
        todo = [(k, c) for k, c in enumerate(picked) if not store.path("check", f"check={k:03d}").exists()]
        if len(todo) < len(picked):
            logger.info("closure: %d of %d checks found on disk", len(picked) - len(todo), len(picked))
        jobs = (delayed(_indexed)(k, settings["model"], settings.get("effects"), c.effect, c.location,
                                  c.linear_values, base.alpha, freqs, u, settings["max_moves"],
                                  settings["alpha_bounds"]) for k, c in todo)
        if todo:
            parallel = Parallel(n_jobs=settings.get("n_jobs", 1), backend="loky", return_as="generator_unordered")
            for k, record in parallel(jobs):
                store.write_table("check", f"check={k:03d}", pd.DataFrame([record]))
                logger.info("closure check %d/%d: %s at %s, rss %.3g (%d FE solves)", k + 1, len(picked),
                            record["effect"], record["location"], record["rss"], record["evaluations"])
        parts = [pd.read_parquet(store.path("check", f"check={k:03d}")) for k in range(len(picked))]
        checks = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
            columns=["effect", "screened_location", "location", "moved_from", "values", "alpha", "rss",
                     "evaluations", "seconds", "message"])
        store.write_table("check", "checks", checks)
        store.finish("check", ["checks"], {"n": len(checks)})
    return store.info("check")


def _indexed(k, *args):
    return k, check_candidate(*args)


@task(name="closure-decide", cache_policy=NO_CACHE)
def decide_task(root: str, settings: dict, freqs: np.ndarray, sensors: np.ndarray, u: np.ndarray,
                run_info: dict) -> dict:
    """Scores, the decision, the updated model, residual tables and ``closure.json``.

    Returns ``closure.json`` as written; a finished decision (its stage and the file) is read back, not
    decided again (the forward selection and the intervals are the closure's costliest step after the checks).
    """
    store = ClosureStore(root)
    if store.is_finished("decide") and (store.root / "closure.json").is_file():
        _logger().info("closure: decision finished earlier, read back")
        return json.loads((store.root / "closure.json").read_text())
    model = load_model(settings["model"])
    library = _library(model, settings)
    base = _baseline_fit(store, model, freqs, u)
    before_info = store.info("baseline")["analysis"]
    before = analyse_residual(base.residual, freqs, base.n_parameters, settings["noise"], settings["significance"],
                              base.relative(u))
    screened = {(c.effect, c.location): c for c in _screened(store)}
    checked = []
    for r in store.read_table("check", "checks").itertuples(index=False):
        c = screened.get((r.effect, r.screened_location))
        c = screening.Candidate(effect=r.effect, location=r.location, n_locations=c.n_locations,
                           linear_values=c.linear_values, linear_rss=c.linear_rss,
                           linear_explained=c.linear_explained, linear_delta_bic=c.linear_delta_bic,
                           linear_delta_ebic=c.linear_delta_ebic, moved_from=json.loads(r.moved_from))
        c.fit = _fit_from_parameters(model, library, freqs, u, json.loads(r.alpha), r.effect, r.location,
                                     json.loads(r.values), r.evaluations, r.seconds, r.message)
        checked.append(c)
    checked = decisions.dedupe(checked)
    chosen = decisions.decide(base, before, checked)
    final = chosen.fit if chosen is not None else base
    after = analyse_residual(final.residual, freqs, final.n_parameters, before.sigma, settings["significance"],
                             final.relative(u))
    ranked = decisions.rank(decisions.merge(checked, list(screened.values())))
    steps, implausible = ([chosen] if chosen is not None else []), [c for c in checked if c.implausible]
    sel = None
    if chosen is not None:
        # Forward selection beyond the first effect (all effects refitted at each step, swaps), in one call;
        # with the first round's checks as the rivals of the first effect.
        sel = forward_select(model, freqs, u, final, after, list(library.values()),
                             significance=settings["significance"], per_type=settings["per_type"],
                             max_moves=settings["max_moves"], alpha_bounds=tuple(settings["alpha_bounds"]),
                             max_effects=settings.get("max_effects", 3), steps=[chosen], rounds=[ranked])
        steps = sel.steps
        implausible += [c for c in sel.implausible if all(c is not d for d in implausible)]
        final, after = sel.final, sel.after
    verdict = decisions.verdict(before, after, len(steps), True if sel is None else sel.identified)
    cand_df = _candidates_frame(ranked, library)
    if not store.is_finished("decide"):
        store.write_table("decide", "candidates", cand_df)
        store.write_table("decide", "residual_after", residual_table(freqs, sensors, final.relative(u),
                                                                     final.residual))
        store.finish("decide", ["candidates", "residual_after"], {"chosen": None if chosen is None else
                                                                 [chosen.effect, chosen.location],
                                                                 "verdict": verdict})
    # The report-facing copies: (frequency_hz, sensor, residual) at the closure folder's top.
    for name, step in (("residual_before", "baseline"), ("residual_after", "decide")):
        atomic_write_bytes(store.root / f"{name}.parquet", store.path(step, name).read_bytes())
    summary = _closure_json(store, settings, run_info, base, final, chosen, before, after, ranked, library, u,
                            sensors, freqs, before_info)
    summary.update(_verdict_json(verdict, steps, implausible, library, final, sel))
    # Issue 19: 95 % intervals and the covariance of alpha and every added effect's value (the effects of the
    # forward selection, in the order added, as in parameters_after).
    from tasks.closure_intervals import closure_interval_fields

    summary.update(closure_interval_fields(model, freqs, u, final, list(summary["parameters_after"]),
                                           settings["noise"], settings["alpha_bounds"]))
    atomic_write_bytes(store.root / "frf_closure.parquet", _parquet_bytes(pd.DataFrame({
        "frequency_hz": np.repeat(freqs, len(sensors)), "sensor": np.tile(np.asarray(sensors, np.int64), len(freqs)),
        "measured": u.ravel(), "alpha_only": base.model_amplitude.ravel(), "extended": final.model_amplitude.ravel()})))
    summary["frf_table"] = "frf_closure.parquet"
    atomic_write_json(store.root / "closure.json", summary)
    try:
        from tasks.closure_plot import plot_residuals

        summary["plot"] = str(plot_residuals(store.root))
        atomic_write_json(store.root / "closure.json", summary)
    except Exception as exc:  # the figure is a convenience; the tables and JSON are the result
        _logger().warning("closure: residual plot not written: %s", exc)
    return json.loads((store.root / "closure.json").read_text())  # as a resumed closure returns it


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
