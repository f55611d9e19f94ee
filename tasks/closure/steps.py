"""The closure's Prefect tasks, one per step: :func:`baseline_task`, :func:`screen_task`, :func:`check_task`
(full FE checks in parallel worker processes, :func:`check_candidate`) and :func:`decide_task` (the
decision, the forward selection and ``closure.json``); with their settings (:class:`ClosureSettings`)
and the effect library (:func:`effect_library`). A finished step is read back from the
:class:`~tasks.closure.store.ClosureStore`, not recomputed."""

from __future__ import annotations

import functools
import json
import time

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.closure import decisions, fits, screening
from fe_core.closure.effects import extended_frf
from fe_core.closure.far.misfit import judge_misfit
from fe_core.closure.far.plausible import mark_first_negligible
from fe_core.closure.far.shifts import own_error, unclaimed
from fe_core.model_error import floor_of
from fe_core.closure.far.search import alpha_restarts
from fe_core.closure.selection import forward_select
from fe_core.inference.residual import analyse_residual, log_residual
from fe_core.threads import at_most
from tasks.closure.store import (
    ClosureStore,
    _baseline_fit,
    _done,
    _fit_from_parameters,
    _logger,
    _param_table,
    _parquet_bytes,
    _screened,
    residual_table,
)
from tasks.closure.handover import evidence_picks, restarts
from tasks.closure.library import cached_library as _cached_library
from tasks.closure.parallel import check_workers, process_checks
from tasks.closure.summary import _candidates_frame, _closure_json, _verdict_json
from tasks.common import beating, heartbeat
from tasks.fe_runs import run_cores
from tasks.runstore import atomic_write_bytes, atomic_write_json

__all__ = [
    "ClosureSettings",
    "effect_library",
    "baseline_task",
    "screen_task",
    "check_candidate",
    "check_task",
    "emulated_check",
    "decide_task",
    "measured",
    "noise_of",
]


# -- settings -------------------------------------------------------------------------------------------
class ClosureSettings(dict):
    """Settings of one closure (a plain dict, stored in ``settings.json``).

    Keys: ``model``, ``measured``, ``alpha_start`` (list), ``noise`` (float or
    None = estimated), ``significance``, ``per_type``, ``max_moves``,
    ``restarts``, ``seed``, ``effects`` (list of registered names or None),
    ``alpha_bounds`` (pair), ``n_jobs``, ``max_effects`` (forward selection), ``emulator`` (the emulated
    search's point mass among the checks where the baseline is far off: :func:`emulated_check`),
    ``max_minutes`` (the closure's time limit: no forward-selection round, check or swap starts after it,
    counted from the closure's start in this process; like ``n_jobs`` it may change on a resume).
    """

    DEFAULTS = dict(noise=None, significance=0.01, per_type=1, max_moves=6, restarts=8, seed=0, effects=None,
                    alpha_bounds=list(fits.ALPHA_BOUNDS), n_jobs=1, check_noise=False,
                    max_effects=3, emulator=False, max_minutes=15.0)

    @classmethod
    def make(cls, **kwargs) -> "ClosureSettings":
        out = cls(cls.DEFAULTS)
        out.update({k: v for k, v in kwargs.items() if v is not None or k not in cls.DEFAULTS})
        return out


def _library(model, settings) -> dict:
    return _cached_library(model, settings.get("effects"))


def effect_library(model, effects=None) -> dict:
    """The effect library of a model (``ValueError`` for an effect that does not apply to it), built once per
    process."""
    return _cached_library(model, effects)


def noise_of(problem, settings: dict):
    """The noise the closure's tests take (:meth:`fe_core.inference.frf_data.FRFData.noise_spec` on the complete
    lines): ``--noise`` as configured, else the noise the measurement states, else the model of a relative term and
    a floor per channel estimated from each residual."""
    return problem.data.noise_spec(settings["noise"])


def measured(problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frequencies (p,), channel numbers (n,), amplitudes (p, n)) the closure fits: the run's measured data
    (``problem.data``, :class:`fe_core.inference.frf_data.FRFData`) on the lines where every channel is kept."""
    freqs, u = problem.data.complete()
    return freqs, np.asarray(problem.data.sensors), u


# -- tasks ---------------------------------------------------------------------------------------------
def on_the_cores(fn):
    """A step's PARDISO calls in this process on the closure's cores (``settings["n_jobs"]``,
    :func:`tasks.fe_runs.run_cores`): nothing runs beside a step's own work here (its full checks run in worker
    processes, one thread each, while this process waits). hb06's model (25,128 DOFs): a response with its Krylov
    space 2.0 -> 1.3-1.5 s on 2 threads (``python -m benchmarks.closure_threads``). Decorate below ``@task``; the
    task's third argument is the settings."""
    @functools.wraps(fn)
    def run(root, problem, settings, *args, **kwargs):
        from fe_core.solvers import pardiso

        with pardiso.threads(run_cores(settings)):
            return fn(root, problem, settings, *args, **kwargs)
    return run


@task(name="closure-baseline", cache_policy=NO_CACHE)
@beating("closure baseline (alpha-only least squares from the run's parameters and the restarts)")
@on_the_cores
def baseline_task(root: str, problem, settings: dict) -> dict:
    """Alpha-only least squares from the run's parameters; residual and its analysis. ``problem``: the run's
    :class:`tasks.problem.Problem` (its model and measured data: the closure fits :func:`measured`)."""
    store = ClosureStore(root)
    freqs, sensors, u = measured(problem)
    if not _done(store, "baseline"):
        model = problem.model
        fit, analysis = fits.baseline(model, freqs, u, settings["alpha_start"], noise_of(problem, settings),
                                      settings["significance"], restarts(store, model, settings), settings["seed"],
                                      tuple(settings["alpha_bounds"]), far_restarts=alpha_restarts)
        store.write_table("baseline", "baseline", _param_table(fit, {}))
        store.write_table("baseline", "residual_before",
                          residual_table(freqs, sensors, fit.relative(u), fit.residual))
        # The later steps rebuild the fit from these (store._baseline_fit), not from an FE solve each.
        store.write_table("baseline", "amplitude",
                          pd.DataFrame({"amplitude": np.asarray(fit.model_amplitude, float).ravel()}))
        # Structure no larger than one mode half a per cent off: the model's own error, unless effects take it to the
        # noise (fe_core.closure.far.shifts.unclaimed, in the decision).
        # Where the model can be refined, the bar is what it leaves against its own refined mesh.
        floor = floor_of(model, freqs, fit.alpha, log=_logger()) if analysis.structured else None
        shifts = (own_error(model, freqs, u, fit, analysis.sigma, None if floor is None else floor.rms)
                  if analysis.structured else None)
        store.finish("baseline", ["baseline", "residual_before", "amplitude"],
                     {"analysis": analysis.to_dict(), "evaluations": fit.evaluations, "seconds": fit.seconds,
                      "message": fit.message, "own_error": None if shifts is None else shifts.to_dict(),
                      "mesh_floor": None if floor is None else floor.to_dict()})
        _logger().info("closure baseline: %s%s", analysis.summary(), "" if shifts is None else f"; {shifts.reason()}")
    return store.info("baseline")


@task(name="closure-screen", cache_policy=NO_CACHE)
@beating("closure screen (every candidate effect, linearised)")
@on_the_cores
def screen_task(root: str, problem, settings: dict) -> dict:
    """Linearised explained share of every candidate effect at the baseline."""
    store = ClosureStore(root)
    freqs, _, u = measured(problem)
    if not _done(store, "screen"):
        t0 = time.perf_counter()
        model = problem.model
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


def check_candidate(ref, effects, kind: str, location: str, linear_values, base_alpha, freqs, u,
                    max_moves: int, alpha_bounds, start_alpha=None, base_residual=None) -> dict:
    """One full FE check (runs in a worker process; ``ref``: the model's :class:`tasks.problem.ModelRef`);
    returns a flat record, the fit's model amplitudes with it (the decision rebuilds the fit from them, no FE solve).
    ``start_alpha``: where the exact search fitted alpha with the candidate (the check starts there);
    ``base_residual``: the baseline's residual (else one FE solve here). The checks fill the cores between them:
    each one's pieces run in its own thread."""
    with at_most(1):
        return _check_candidate(ref, effects, kind, location, linear_values, base_alpha, freqs, u, max_moves,
                                alpha_bounds, start_alpha, base_residual)


def _check_candidate(ref, effects, kind, location, linear_values, base_alpha, freqs, u, max_moves, alpha_bounds,
                     start_alpha, base_residual=None) -> dict:
    model = ref.load()
    library = _cached_library(model, effects)
    cand = screening.Candidate(effect=kind, location=location, n_locations=len(library[kind].locations()),
                               linear_values=np.asarray(linear_values, float), linear_rss=0.0, linear_explained=0.0,
                               start_alpha=None if start_alpha is None else np.asarray(start_alpha, float))
    base = fits.Fit(alpha=np.asarray(base_alpha, float), effect=None, location=None, values=np.zeros(0),
                    model_amplitude=None, residual=np.full(np.shape(u), np.inf), evaluations=0)
    # The base residual is only compared against (a fit worse than it restarts from zero):
    base.residual = (np.asarray(base_residual, float) if base_residual is not None else
                     log_residual(np.abs(extended_frf(model, base.alpha, freqs)), u))
    screening.check(model, freqs, u, base, library[kind], cand, max_moves, tuple(alpha_bounds))
    f = cand.fit
    return {"effect": kind, "screened_location": location, "location": f.location,
            "moved_from": json.dumps(cand.moved_from), "values": json.dumps(list(map(float, f.values))),
            "alpha": json.dumps(list(map(float, f.alpha))), "rss": f.rss, "evaluations": f.evaluations,
            "seconds": f.seconds, "message": f.message, "start": f.start,
            "amplitude": np.asarray(f.model_amplitude, float).ravel()}


@task(name="closure-check", cache_policy=NO_CACHE)
@on_the_cores
def check_task(root: str, problem, settings: dict) -> dict:
    """Full FE least squares of the best-screened candidates, in parallel, each stored as it finishes."""
    store = ClosureStore(root)
    freqs, _, u = measured(problem)
    logger = _logger()
    if not _done(store, "check"):
        analysis = store.info("baseline")["analysis"]
        screened = _screened(store)
        model = problem.model
        base = _baseline_fit(store, model, freqs, u)
        first, rest = screening.pick_in_waves(screened, settings["per_type"],
                                              fits.checks_per_type(base, settings["per_type"]))
        if not (analysis["structured"] or settings.get("check_noise")):
            logger.info("closure: the residual is noise (chi-square p = %.3g); no candidate is checked",
                        analysis["p_chi2"])
            first, rest = [], []
        elif analysis["structured"] and settings.get("search", True) and fits.far_off(base):
            first, rest = _searched(store, model, settings, base, freqs, u), first + rest
        wave = list(enumerate(first))
        _run_checks(store, problem, settings, base, freqs, u, wave)
        parts = [pd.read_parquet(store.path("check", f"check={k:03d}")) for k, _ in wave]
        if rest:  # far off: the further candidates, where the first wave made no contender
            first_rss = [float(p["rss"].iloc[0]) for p in parts]
            chosen = {id(c) for c in screening.second_wave(rest, first_rss, base.rss)}
            wave = [(len(first) + i, c) for i, c in enumerate(rest) if id(c) in chosen]
            logger.info("closure: far off, %d further candidates checked of %d (%s)", len(wave), len(rest),
                        "no contender in the first wave" if wave else "a contender's moves re-screened its kind")
            _run_checks(store, problem, settings, base, freqs, u, wave)
            parts += [pd.read_parquet(store.path("check", f"check={k:03d}")) for k, _ in wave]
        picked = first + rest
        if picked and settings.get("emulator") and fits.far_off(base):
            if not store.path("check", "check=emulated").exists():
                record = emulated_check(model, settings, base, freqs, u)
                if record is not None:
                    store.write_table("check", "check=emulated", pd.DataFrame([record]))
            if store.path("check", "check=emulated").exists():
                parts.append(pd.read_parquet(store.path("check", "check=emulated")))
        checks = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
            columns=["effect", "screened_location", "location", "moved_from", "values", "alpha", "rss",
                     "evaluations", "seconds", "message", "start"])
        store.write_table("check", "checks", checks)
        store.finish("check", ["checks"], {"n": len(checks)})
    return store.info("check")


def emulated_check(model, settings: dict, base, freqs, u) -> dict | None:
    """The emulated search's point mass (:func:`strategies.closure_emulator.emulated_search`, in this process) as a
    check record; its ``evaluations`` count the search's FE runs. None where the library has no point mass or its
    nodes no positions (a matrices model)."""
    from strategies.closure_emulator import EmulatorOptions, emulated_candidate, emulated_search

    effect = _library(model, settings).get("point_mass")
    if effect is None or not effect.locations() or effect.position(effect.locations()[0]) is None:
        _logger().info("closure: no emulated search (no point mass with node positions in the library)")
        return None
    found = emulated_search(model, freqs, u, effect, base.alpha, noise=settings["noise"],
                            options=EmulatorOptions(seed=settings.get("seed", 0)),
                            alpha_bounds=tuple(settings["alpha_bounds"]), refine_moves=settings["max_moves"])
    c = emulated_candidate(found, effect)
    f = c.fit
    _logger().info("closure: %s", found.summary())
    return {"effect": c.effect, "screened_location": c.location, "location": c.location,
            "moved_from": json.dumps(c.moved_from), "values": json.dumps(list(map(float, f.values))),
            "alpha": json.dumps(list(map(float, f.alpha))), "rss": f.rss, "evaluations": f.evaluations,
            "seconds": found.seconds, "message": f.message, "start": f.start,
            "amplitude": None if f.model_amplitude is None else np.asarray(f.model_amplitude, float).ravel()}


def _run_checks(store, problem, settings: dict, base, freqs, u, wave) -> None:
    """Check the ``(index, candidate)`` pairs of ``wave`` not yet on disk, in parallel, each stored as it ends."""
    logger = _logger()
    todo = [(k, c) for k, c in wave if not store.path("check", f"check={k:03d}").exists()]
    if len(todo) < len(wave):
        logger.info("closure: %d of %d checks found on disk", len(wave) - len(todo), len(wave))
    if not todo:
        return
    jobs = (delayed(_indexed)(k, problem.ref, settings.get("effects"), c.effect, c.location, c.linear_values,
                              base.alpha, freqs, u, settings["max_moves"], settings["alpha_bounds"], c.start_alpha,
                              base.residual)
            for k, c in todo)
    n_jobs = check_workers(problem, min(len(todo), run_cores(settings)))  # as many as the memory left holds
    parallel = Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
    count = [len(wave) - len(todo)]
    with heartbeat("closure checks", lambda: f"{count[0]} of {len(wave)} candidates checked"):
        for k, record in parallel(jobs):
            store.write_table("check", f"check={k:03d}", pd.DataFrame([record]))
            count[0] += 1
            logger.info("closure check %d of %d (candidate %d): %s at %s, rss %.3g (%d FE solves)", count[0],
                        len(wave), k + 1, record["effect"], record["location"], record["rss"], record["evaluations"])


def _searched(store, model, settings: dict, base, freqs, u) -> list:
    """Far off: the exact search's candidates (:func:`fe_core.closure.far.picks.search_candidates`), found in the
    main process on the reduced model and stored (``check/search.json``); read back on resume."""
    from fe_core.closure.far.picks import as_candidate, pick_found
    from fe_core.closure.far.search import Found

    path = store.root / "step=check" / "search.json"
    if path.is_file():
        record = json.loads(path.read_text())
    else:
        from fe_core.closure.far.picks import search_candidates

        _, record = search_candidates(model, freqs, u, base, list(_library(model, settings).values()),
                                      alpha_bounds=tuple(settings["alpha_bounds"]))
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(path, record)
    library = _library(model, settings)
    found = [Found(f["effect"], f["location"], np.asarray(f["values"]), np.asarray(f["alpha"]), f["scan"], f["rss"],
                   len(library[f["effect"]].locations())) for f in record["found"]]
    picked = {tuple(p) for p in record["picked"]}
    picks = [f for f in pick_found(found) if (f.effect, f.location) in picked]
    # The closure starts from the evidence too: what the update's exact screens found, with their alpha.
    picks = evidence_picks(store, model, library, picks, found)
    _logger().info("closure: far off (rms %.3g): exact search of %d places in %.1f s; checking %s",
                   float(np.sqrt(np.mean(base.residual ** 2))), sum(p["scanned"] for p in record["passes"]),
                   record["seconds"], ", ".join(f"{f.effect} at {f.location} = {f.values[0]:.4g}" for f in picks))
    return [as_candidate(f, base) for f in picks]


def _indexed(k, *args):
    return k, check_candidate(*args)


@task(name="closure-decide", cache_policy=NO_CACHE)
@beating("closure decision (forward selection, moves, swaps, intervals)")
@on_the_cores
def decide_task(root: str, problem, settings: dict, run_info: dict, deadline: float | None = None) -> dict:
    """Scores, the decision, the updated model, residual tables and ``closure.json``.

    ``deadline`` (``time.time()`` seconds): the forward selection starts nothing after it (``max_minutes``).

    Returns ``closure.json`` as written; a finished decision (its stage and the file) is read back, not
    decided again (the forward selection and the intervals are the closure's costliest step after the checks).
    """
    store = ClosureStore(root)
    if store.is_finished("decide") and (store.root / "closure.json").is_file():
        _logger().info("closure: decision finished earlier, read back")
        return json.loads((store.root / "closure.json").read_text())
    model = problem.model
    freqs, sensors, u = measured(problem)
    library = _library(model, settings)
    base = _baseline_fit(store, model, freqs, u)
    noise = noise_of(problem, settings)
    before = analyse_residual(base.residual, freqs, base.n_parameters, noise, settings["significance"],
                              base.relative(u))
    screened = {(c.effect, c.location): c for c in _screened(store)}
    checked = []
    for r in store.read_table("check", "checks").itertuples(index=False):
        c = screened.get((r.effect, r.screened_location)) or screening.Candidate(
            effect=r.effect, location=r.screened_location, n_locations=len(library[r.effect].locations()),
            linear_values=np.asarray(json.loads(r.values), float), linear_rss=float(r.rss), linear_explained=0.0)
        c = screening.Candidate(effect=r.effect, location=r.location, n_locations=c.n_locations,
                                linear_values=c.linear_values, linear_rss=c.linear_rss,
                                linear_explained=c.linear_explained, linear_delta_bic=c.linear_delta_bic,
                                linear_delta_ebic=c.linear_delta_ebic, moved_from=json.loads(r.moved_from))
        c.fit = _fit_from_parameters(model, library, freqs, u, json.loads(r.alpha), r.effect, r.location,
                                     json.loads(r.values), r.evaluations, r.seconds, r.message,
                                     amplitude=getattr(r, "amplitude", None))
        c.fit.start = str(getattr(r, "start", "") or "")  # stores written before the joint fit's starts lack it
        checked.append(c)
    from fe_core.closure.decisions import dedupe_counting  # a tie with the emulated search keeps its FE solves

    checked = dedupe_counting(checked)
    if before.structured:  # the first effect's size rule (fe_core.closure.far.plausible)
        mark_first_negligible(model, freqs, base, checked, before.sigma)
    chosen = decisions.decide(base, before, checked)
    final = chosen.fit if chosen is not None else base
    # Tested against the configured noise, else the level estimated from this residual itself (never the first
    # residual's estimate when that residual was structure: an upper bound, not the noise).
    after = analyse_residual(final.residual, freqs, final.n_parameters, noise, settings["significance"],
                             final.relative(u))
    ranked = decisions.rank(decisions.merge(checked, list(screened.values())))
    steps, implausible = ([chosen] if chosen is not None else []), [c for c in checked if c.implausible]
    sel, times = None, {}
    if chosen is not None:
        # Forward selection beyond the first effect (all effects refitted at each step, swaps), in one call;
        # with the first round's checks as the rivals of the first effect.
        sel = forward_select(model, freqs, u, final, after, list(library.values()),
                             significance=settings["significance"], per_type=settings["per_type"],
                             max_moves=settings["max_moves"], alpha_bounds=tuple(settings["alpha_bounds"]),
                             max_effects=settings.get("max_effects", 3), steps=[chosen], rounds=[ranked],
                             baseline=base, times=times, out_of_time=None if deadline is None else
                             (lambda margin=0.0: time.time() + margin > deadline),
                             check_many=process_checks(problem, settings, library))
        _logger().info("closure: forward selection %s", ", ".join(f"{k} {v:.0f} s" for k, v in times.items()))
        steps = sel.steps
        implausible += [c for c in sel.implausible if all(c is not d for d in implausible)]
        final, after = sel.final, sel.after
    own = store.info("baseline").get("own_error") or {}
    left = unclaimed(own.get("within", False), len(steps), after.structured,
                     sel is None or sel.stopped != "time limit")
    not_claimed = _verdict_json("noise", steps, [], library, final, sel)["effects"] if left and steps else []
    for e in not_claimed:
        e["status"] = "not claimed (within the model's own error)"
    if left:  # nothing claimed: the alpha-only fit is the model after; the effects fitted are listed, not claimed
        steps, final, after, sel = [], base, before, None
    # The structure left beyond the noise: the model's own misfit when nothing more stands out from it and it is small
    # beside what the effects explained (fe_core.closure.far.misfit.judge_misfit); closure.json reports its size.
    misfit = judge_misfit(base.residual, final.residual, after.sigma, sel is not None and sel.stopped ==
                          "nothing stands out", bar=own.get("bar") if own.get("floor") else None)
    verdict = decisions.verdict(before, after, len(steps), True if sel is None else sel.identified,
                                misfit.own and after.structured, left)
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
    # The run's own parameters on the closure's measure (one FE solve), so that "before" is not mistaken for the
    # run's reported error when the run fitted another residual (complex, other lines).
    at_run = np.abs(extended_frf(model, np.asarray(settings["alpha_start"], float), freqs)) / u - 1.0
    summary = _closure_json(store, settings, run_info, base, final, before, after, ranked, library, u, sensors,
                            freqs, _verdict_json(verdict, steps, implausible, library, final, sel),
                            float(np.mean(np.abs(at_run))))
    summary.update(misfit.to_dict())
    summary["own_error"], summary["not_claimed"] = own or None, not_claimed
    if steps and after.structured:
        summary["decision"] += f"; {misfit.reason}"
    elif left:   # not "no checked candidate lowers the extended BIC": some may have, short of the noise
        summary["decision"] = f"no effect claimed: {own['reason']}" + (
            f" ({len(not_claimed)} effect(s) fitted leave structure: not claimed, see not_claimed)"
            if not_claimed else "")
    summary["selection_stopped"] = "the model's own error" if left else sel.stopped if sel is not None else None
    summary["selection_seconds"] = {k: round(v, 1) for k, v in times.items()}  # per stage of the forward selection
    summary["max_minutes"] = settings.get("max_minutes")
    if sel is not None and sel.stopped == "time limit":
        summary["decision"] += (f"; the closure's time limit ({settings['max_minutes']:g} min) stopped the forward "
                                f"selection before it finished (--closure-minutes)")
    search = store.root / "step=check" / "search.json"
    if search.is_file():
        record = json.loads(search.read_text())
        summary["search"] = {k: record[k] for k in ("seconds", "rss_alpha", "picked", "passes") if k in record}
    # Issue 19: 95 % intervals and the covariance of alpha and every added effect's value (the effects of the
    # forward selection, in the order added, as in parameters_after).
    from tasks.closure.intervals import closure_interval_fields

    summary.update(closure_interval_fields(model, freqs, u, final, list(summary["parameters_after"]),
                                           settings["noise"], settings["alpha_bounds"]))
    atomic_write_bytes(store.root / "frf_closure.parquet", _parquet_bytes(pd.DataFrame({
        "frequency_hz": np.repeat(freqs, len(sensors)), "sensor": np.tile(np.asarray(sensors, np.int64), len(freqs)),
        "measured": u.ravel(), "alpha_only": base.model_amplitude.ravel(), "extended": final.model_amplitude.ravel()})))
    summary["frf_table"] = "frf_closure.parquet"
    atomic_write_json(store.root / "closure.json", summary)
    try:
        from tasks.closure.plot import plot_residuals

        summary["plot"] = str(plot_residuals(store.root))
        atomic_write_json(store.root / "closure.json", summary)
    except Exception as exc:  # the figure is a convenience; the tables and JSON are the result
        _logger().warning("closure: residual plot not written: %s", exc)
    return json.loads((store.root / "closure.json").read_text())  # as a resumed closure returns it
