"""Close the loop on a finished updating run: ``python -m flows.diagnose --run-id ID``.

Reads the run's ``summary.json`` (its updated parameters) and ``manifest.json``
(model and measured data), then, as a Prefect flow ``diagnose-<run-id>``:

1. ``closure-baseline``: alpha-only least squares from the run's parameters
   (plus ``--restarts`` Sobol starts), the residual per sensor and frequency,
   its noise level (configured with ``--noise`` or estimated) and the
   chi-square decision noise / structure;
2. ``closure-screen``: every candidate effect of the library
   (:mod:`fe_core.closure.effects`) linearised at that point;
3. ``closure-check``: full FE least squares of the best candidates
   (only when the residual is structure);
4. ``closure-decide``: extended-BIC decision, the updated model, residual
   tables, ``closure.json`` and ``residuals.png``.

Everything goes to ``<run folder>/closure/`` (``--name`` for another folder);
a finished step is read back on a second call, so a killed diagnosis resumes.

Measured data: the closure traces the amplitude residual of the model's
sensors under its default excitation. Legacy data (sensor numbers) are used
as they are; channel data (response, reference) must be every sensor of the
model under its default excitation (a hammer test: name the hammer as the
model file's ``excitation``), and then the closure uses the amplitudes of the
lines the run selected where every channel passed the coherence threshold
(:func:`closure_data`); the phase of complex data is not used here.

Examples::

    python -m flows.diagnose --run-id pso-3
    python -m flows.diagnose --run-id pso-3 --noise 0.005 --effects point_mass,grounded_spring
    python -m flows.update --measured data/cases/three_plate_effects/point_mass.csv --close-loop --noise 0.005
"""

from __future__ import annotations

from flows import environment  # noqa: F401  (first: the environment Prefect starts in)

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from prefect import flow  # noqa: E402

from fe_core.closure.fits import ALPHA_BOUNDS  # noqa: E402
from fe_core.closure.effects import registered_effects  # noqa: E402
from flows.config import REPO, ConfigError  # noqa: E402
from flows.local_api import start_early  # noqa: E402
from tasks.closure.summary import STATUSES  # noqa: E402
from tasks.problem import Problem  # noqa: E402
from tasks.runstore import atomic_write_json  # noqa: E402
from tasks.closure import steps as ct  # noqa: E402
from tasks.io.measured import MeasuredDataError  # noqa: E402
from tasks.io.summary import read_summary  # noqa: E402

__all__ = ["diagnose_flow", "diagnose", "run_folder", "main", "print_closure", "print_closure_intervals"]


class DiagnoseError(ValueError):
    """A run folder or setting the diagnosis cannot use; the message names the file or key."""


def run_folder(run_id: str, runs_dir: str | Path = "runs") -> tuple[Path, dict, dict]:
    """The folder of a finished single run, its summary and manifest.

    For a run with repeats, the repeat with the smallest overall error is used.
    """
    root = Path(runs_dir)
    root = (root if root.is_absolute() else REPO / root) / run_id
    summary_path = root / "summary.json"
    if not summary_path.exists():
        raise DiagnoseError(f"{summary_path}: no summary.json; is run {run_id!r} finished?")
    summary = read_summary(summary_path)  # an older record in the current shape
    if summary.get("kind") == "modal":
        raise DiagnoseError(f"{summary_path}: run {run_id!r} is a modal update; its closure runs with the update "
                            "(summary.json's closure), not python -m flows.diagnose")
    if "runs" in summary:  # repeats: diagnose the best one
        best = min(summary["runs"], key=lambda r: r["overall_error"])
        root = Path(best["run_folder"])
        summary = best
    manifest_path = root / "manifest.json"
    if not manifest_path.exists():
        raise DiagnoseError(f"{manifest_path}: no manifest.json; is {root} a run folder?")
    manifest = json.loads(manifest_path.read_text())
    if "parameters" not in summary:
        raise DiagnoseError(f"{summary_path}: no 'parameters' key")
    return root, summary, manifest


def closure_data(data, model):
    """The run's measured data (:class:`tasks.update_data.UpdateData`, the object the update fitted) as the
    closure takes it: every sensor of the model under its default excitation (see the module docstring); the
    closure fits the amplitudes of the lines where every channel is kept (``data.complete()``). Raises
    DiagnoseError for channel data the closure cannot use."""
    if data.channels is not None:
        refs = sorted({c["excitation"] for c in data.channel_info})
        raise DiagnoseError(f"{data.source}: the closure traces the residual of every sensor of the model under its "
                            f"default excitation ({model.excitation_name!r}); these data have {data.n_channels} "
                            f"channels under {', '.join(map(repr, refs))}: name that excitation in the model file "
                            f"(excitation = \"{refs[0]}\") and measure every sensor, or diagnose legacy data")
    return data


def run_problem(cfg: dict, measured: str | None = None):
    """The finished run's problem (model, data), read once, as the run resolved it from its manifest's ``config``;
    ``measured``: another file. For scripts that study a stored run (``benchmarks.closure_threads``,
    ``benchmarks.heldout_crossband``) as the closure does."""
    from flows.config import UpdateConfig, stored_settings
    from flows.problem import stored_problem

    try:
        config = UpdateConfig(**stored_settings(cfg))
        if measured is not None:  # another measurement of the same structure: its amplitudes
            config = config.replace(measured=str(measured), residuals="amplitude")
        return stored_problem(config)
    except ConfigError as exc:
        raise DiagnoseError(str(exc)) from None


_SELECTION_KEYS = ("lines", "line_windows", "resonance_widen", "min_coherence")


#: The last share of the closure's time limit in which the forward selection starts nothing (no round, check, refinement
#: or swap): it is left for the backward check and the intervals, which always run (held-out hd04 and hd09: 75 s and
#: 128 s of backward check after their 15-minute limits, 18 min in all).
SELECTION_RESERVE = 0.1
#: ``flows.update --close-loop`` without ``--closure-minutes``: the closure gets what is left of this many minutes since
#: the command began (issue 40's time per case), less COMMAND_TAIL_MINUTES, but at least CLOSURE_MIN_MINUTES (its
#: baseline, screen and first checks take 2-5 min on the held-out cases of up to 30k DOFs).
COMMAND_MINUTES, CLOSURE_MIN_MINUTES = 15.0, 5.0
#: What the command spends outside the clocks of the update and the closure: the interpreter's start and imports before
#: ``main`` starts its clock, the closure's printout, stopping Prefect's temporary server. Held-out hh09 (session 30):
#: its closure ended 3 s inside its 10-minute limit and the command took 908 s, 8 s over the 15 minutes.
COMMAND_TAIL_MINUTES = 0.5


def closure_minutes_left(elapsed_seconds: float) -> float:
    """The default time limit of ``--close-loop``'s closure after an update of ``elapsed_seconds``, in minutes rounded
    down to a tenth (never above what is left)."""
    left = COMMAND_MINUTES - COMMAND_TAIL_MINUTES - elapsed_seconds / 60.0
    return max(CLOSURE_MIN_MINUTES, math.floor(10.0 * left + 1e-9) / 10.0)


#: Why a run that updated mass factors is not closed (the closure's fits and effects are alpha-based).
MASS_FACTORS_REFUSED = ("the run updates mass factors ({names}); the closure refits the stiffness factors alpha only "
                        "(its segment_mass effect is how it tests a segment's mass), so it would drop them: close "
                        "the loop on a run whose model file updates stiffness only")


@flow(name="diagnose", flow_run_name="diagnose-{run_id}", log_prints=True)
def diagnose_flow(run_id: str, closure_root: str, settings: dict, run_info: dict, problem) -> dict:
    """The closure of one run as four tasks; returns the content of ``closure.json``. ``problem``: the run's model
    and measured data (resolved once, :class:`tasks.problem.Problem`; the data as :func:`closure_data`)."""
    t0 = time.perf_counter()
    limit = settings.get("max_minutes")
    deadline = None if limit is None else time.time() + 60.0 * float(limit) * (1.0 - SELECTION_RESERVE)
    ct.baseline_task(closure_root, problem, settings)
    ct.screen_task(closure_root, problem, settings)
    ct.check_task(closure_root, problem, settings)
    summary = ct.decide_task(closure_root, problem, settings, run_info, deadline)
    summary["wall_seconds"] = round(time.perf_counter() - t0, 3)
    atomic_write_json(Path(closure_root) / "closure.json", summary)  # the record is what the command returns
    return summary


def diagnose(run_id: str, runs_dir: str | Path = "runs", name: str = "closure", measured: str | None = None,
             problem=None, **options) -> dict:
    """Diagnose a finished run (see the module docstring); ``options`` are :class:`tasks.closure.ClosureSettings`.

    ``problem``: the run's :class:`tasks.problem.Problem` when the caller has it (``flows.update --close-loop``:
    the model and the measured file read once for the update and its closure); else it is resolved from the
    run's manifest. ``measured``: another measured file of the same structure instead of the run's."""
    root, summary, manifest = run_folder(run_id, runs_dir)
    cfg = manifest.get("config", {})
    measured_path = Path(measured or cfg.get("measured", "data/benchmark/measured.csv"))
    measured_path = measured_path if measured_path.is_absolute() else REPO / measured_path
    local_api = start_early()  # a model read here: Prefect's temporary API starts beside it (flows/local_api.py)
    try:
        if problem is None or measured is not None:
            problem = run_problem(cfg, measured)
        prepared = _closure_problem(root, summary, manifest, cfg, problem, measured_path, run_id, name, options)
    except BaseException:
        local_api.abandon()
        raise
    local_api.wait()
    return diagnose_flow(run_id, *prepared)


def _closure_problem(root, summary, manifest, cfg, problem, measured_path, run_id, name, options):
    """The closure's settings checked and written, its run information and problem: ``(closure folder, settings,
    run information, problem)`` for :func:`diagnose_flow`."""
    selection = {k: cfg[k] for k in _SELECTION_KEYS if k in cfg}
    model_name = cfg.get("model", "three_plate")
    model, ref = problem.model, problem.ref
    data = closure_data(problem.data, model)  # refuse channel data first
    gammas = [k for k in summary["parameters"] if k.startswith("gamma_")]
    if gammas:
        raise DiagnoseError(f"{root / 'summary.json'}: {MASS_FACTORS_REFUSED.format(names=', '.join(gammas))}")
    names = [f"alpha_{i + 1}" for i in range(len(summary["parameters"]))]
    try:
        alpha = [float(summary["parameters"][n]) for n in names]
    except KeyError as exc:
        raise DiagnoseError(f"{root / 'summary.json'}: parameters lack {exc.args[0]!r}") from None
    lower = max(float(cfg.get("lower", -1.0)), ALPHA_BOUNDS[0])
    upper = float(cfg.get("upper", ALPHA_BOUNDS[1]))
    effects = options.pop("effects", None)
    if effects is not None:
        unknown = [e for e in effects if e not in registered_effects()]
        if unknown:
            raise DiagnoseError(f"unknown effect(s) {', '.join(unknown)}; registered: "
                                f"{', '.join(registered_effects())}")
    if effects is not None:  # an effect that cannot apply to this model is refused before any work
        try:
            ct.effect_library(model, effects)
        except ValueError as exc:
            raise DiagnoseError(f"--effects: {exc}") from None
    settings = ct.ClosureSettings.make(model=model_name, measured=str(measured_path),
                                       alpha_start=alpha, alpha_bounds=[lower, upper], effects=effects,
                                       n_jobs=options.pop("n_jobs", None) or cfg.get("n_jobs", 1), **options)
    if not (settings["noise"] is None or settings["noise"] > 0):
        raise DiagnoseError(f"--noise must be positive, got {settings['noise']}")
    if not 0 < settings["significance"] < 1:
        raise DiagnoseError(f"--significance must lie in (0, 1), got {settings['significance']}")
    if settings["max_minutes"] is not None and not settings["max_minutes"] >= 0:
        raise DiagnoseError(f"--closure-minutes must be zero or positive, got {settings['max_minutes']}")
    closure_root = root / name
    ct.ClosureStore(closure_root).write_settings(dict(settings))
    entry = manifest.get("measured_data", {})
    metric = (f"Eq. (6b) of the run's {entry['residual']} residual over {entry['values']} values" if entry else
              "Eq. (6b) of the run's residual")
    run_info = {"run_id": run_id, "run_folder": str(root), "parameters": summary["parameters"], "selection": selection,
                "overall_error": summary.get("overall_error"), "error_metric": metric}
    problem = Problem(model, ref, data, np.full(len(alpha), lower), np.full(len(alpha), upper),
                      worker_bytes=problem.worker_bytes)
    return str(closure_root), dict(settings), run_info, problem


def print_closure(summary: dict, file=None) -> None:
    """The closure's printout, rendered from closure.json's fields alone (what is printed is what is recorded)."""
    file = file or sys.stdout
    print(file=file)
    print(f"closure: {summary['decision']}", file=file)
    rb, ra = summary["residual_before"], summary["residual_after"]
    print(f"residual before: rms {rb['rms']:.3%}, noise {rb['sigma']:.3%} ({rb['sigma_source']}), chi2 "
          f"{rb['chi2']:.1f} on {rb['dof']} dof, p = {rb['p_chi2']:.3g}", file=file)
    print(f"residual after:  rms {ra['rms']:.3%}, noise {ra['sigma']:.3%} ({ra['sigma_source']}), chi2 "
          f"{ra['chi2']:.1f} on {ra['dof']} dof, p = {ra['p_chi2']:.3g}", file=file)
    verdict = summary.get("verdict")
    if verdict is not None:
        print(f"verdict: {verdict}", file=file)
        for e in summary.get("not_claimed") or []:   # fitted within the model's own error, short of the noise
            print(f"  not claimed: {e['type']} at {e['location']}, {e['parameter']} = {e['value']:.4g} {e['unit']}",
                  file=file)
        for e in summary.get("effects", []):
            evidence = (f", evidence {e['evidence']:.0%} ("
                        f"{'singled out' if e['identified'] else 'not singled out'} among the rivals checked there)")
            moved = f" (moved from {', '.join(e['moved_from'])})" if e.get("moved_from") else ""
            print(f"  {e['step']}. {STATUSES[e['status']]}: {e['type']} at {e['location']}{moved}, {e['parameter']} = "
                  f"{e['value']:.4g} {e['unit']}, explains {e['explained']:.1%} of the residual then{evidence}",
                  file=file)
            if e.get("start"):
                print(f"       joint fit of alpha and the effect: the start '{e['start']}' won", file=file)
            if e.get("locations_95", 0) > 1:
                far = f", up to {e['spread_mm']:.0f} mm away" if e.get("spread_mm") is not None else ""
                pinned = "" if e.get("located", True) else ": the location is not pinned down"
                print(f"       where: {e['locations_95']} locations of this kind hold 95 % of the evidence{far}"
                      f"{pinned}", file=file)
            for r in e.get("rivals", []):
                weight = ("too small to be an effect (the size rule), so not weighed" if r.get("negligible") else
                          f"evidence {r['evidence']:.0%}")
                print(f"       or {r['type']} at {r['location']} = {r['value']:.4g} {r['unit']} (extended BIC "
                      f"{r['delta_ebic']:+.1f}, {weight})", file=file)
        for g in summary.get("combined", []):
            print(f"  steps {' and '.join(map(str, g['steps']))}, {g['span_mm']:.0f} mm apart, are one {g['type']} of "
                  f"{g['value']:.4g} {g['unit']} between their nodes, at ({', '.join(f'{x:.3f}' for x in g['position_m'])})"
                  " m", file=file)
        for s in summary.get("swaps", []):
            print(f"  swapped: {s}", file=file)
        for e in summary.get("implausible", []):
            bound = f" (the {e['at_bound']})" if e.get("at_bound") else ""
            print(f"  implausible (fit ends on a plausibility bound): {e['type']} at {e['location']}, "
                  f"{e['parameter']} = {e['value']:.4g} {e['unit']}{bound}", file=file)
    floor = (f"noise floor {summary['noise_floor']:.3%} ({summary['noise_floor_source']})"
             if summary.get("noise_floor") is not None else f"noise floor {summary.get('noise_floor_source')}")
    print(f"overall error ({summary['error_metric']}): at the run's parameters {summary['error_at_run_parameters']:.3%}"
          f" -> refitted without effects {summary['error_before']:.3%} -> with them {summary['error_after']:.3%}; "
          f"{floor}", file=file)
    if summary.get("error_run") is not None:
        print(f"  (the run reported {summary['error_run']:.3%}: {summary['error_run_metric']})", file=file)
    print("per-sensor error: " + ", ".join(
        f"{k.split('_')[-1]}: {summary['per_sensor_error_before'][k]:.2%} -> {v:.2%}"
        for k, v in summary["per_sensor_error_after"].items()), file=file)
    run = summary.get("parameters_run") or {}
    before, after = summary["parameters_before"], summary["parameters_after"]
    width = max(22, *map(len, after))
    print(f"{'parameter':<{width}} {'run':>9} {'before':>9} {'after':>11}", file=file)
    for k in after:
        r, b = run.get(k), before.get(k)
        print(f"{k:<{width}} {'-' if r is None else f'{r:9.4f}':>9} {'-' if b is None else f'{b:9.4f}':>9} "
              f"{after[k]:>11.4g}", file=file)
    print("(run: the updating run's result; before: alpha-only least squares from it; after: with the effects)",
          file=file)
    print_closure_intervals(summary, file)
    print("candidates (best first):", file=file)
    for c in summary["candidates"][:6]:
        score = (f"explains {c['explained']:.1%}, dEBIC {c['delta_ebic']:+.1f}" if c["checked"]
                 else f"linear {c['linear_explained']:.1%}, dEBIC~{c['linear_delta_ebic']:+.1f}")
        print(f"  {c['rank']:>2}. {c['type']:<16} {c['location']:<16} {c['value']:>11.4g} {c['unit']:<4} {score}",
              file=file)
    if "wall_seconds" in summary:
        print(f"{summary['fe_solves']} FE solves, {summary['wall_seconds']:.1f} s", file=file)


def print_closure_intervals(summary: dict, file=None) -> None:
    file = file or sys.stdout
    """The 95 % intervals of the extended model's parameters (issue 19), if closure.json has them."""
    iv = summary.get("intervals")
    if not iv:
        return
    d, cost = summary["interval_details"], summary["interval_cost"]
    print(f"95 % intervals after the closure: {summary['interval_method']} (Gauss-Newton) at the least-squares "
          f"optimum of the extended model, noise {100 * summary['noise_sigma']:.3g} % ({d['noise_source']}, "
          f"{d['distribution']} quantile {d['quantile']:.3f}); exact Jacobian columns for alpha and every effect; "
          f"cost {cost['jacobians']} Jacobian(s), {cost['seconds']:.2f} s", file=file)
    print(f"{'parameter':<22} {'LS optimum':>11} {'95 % interval':>27} {'std':>10}", file=file)
    for name, (lo, hi) in iv.items():
        est, std = d["estimate"][name], d["std"][name]
        text = "unbounded" if lo is None else f"[{lo:.4g}, {hi:.4g}]"
        print(f"{name:<22} {est:>11.4g} {text:>27} {'inf' if std is None else f'{std:.3g}':>10}", file=file)
    for line in d["flags"]:
        print(line, file=file)
    if not cost["at_optimum"]:
        print("warning: the Gauss-Newton steps did not settle at the optimum; the intervals are approximate",
              file=file)


def add_closure_arguments(p: argparse.ArgumentParser, noise: bool = True) -> None:
    """Options of the closure, shared with ``flows.update --close-loop`` (whose ``--noise`` is the run's setting:
    ``noise=False``)."""
    if noise:
        p.add_argument("--noise", type=float, metavar="SIGMA",
                       help="relative noise of the measured amplitudes, e.g. 0.005 (default: estimated from the "
                            "residual)")
    p.add_argument("--significance", type=float, help="chi-square level for 'structure' (default 0.01)")
    p.add_argument("--effects", metavar="A,B", help="effect types to consider (default all registered: "
                                                    + ", ".join(registered_effects()) + ")")
    p.add_argument("--per-type", type=int, help="candidates per effect type given a full FE check (default 1)")
    p.add_argument("--restarts", type=int, help="extra Sobol starts of the alpha-only baseline fit (default 8)")
    p.add_argument("--closure-name", metavar="NAME", help="sub-folder of the run for the closure (default closure)")
    p.add_argument("--closure-minutes", type=float, metavar="MIN",
                   help="time limit of the closure: no further effect, check, refinement or swap is started in its "
                        "last tenth (left for the backward check and the intervals); what was found by then is "
                        "reported (default 15; with flows.update --close-loop, what is left of 15 min since the "
                        "command began, at least 5)")
    p.add_argument("--closure-emulator", action="store_true",
                   help="where the baseline is far off, also search a point mass globally with the MRGP over "
                        "(alpha, position, log size) and check its fit (docs/guide/closure-emulator.md)")


def closure_options(args) -> dict:
    return dict(noise=args.noise, significance=args.significance, per_type=args.per_type, restarts=args.restarts,
                max_minutes=args.closure_minutes,
                emulator=True if getattr(args, "closure_emulator", False) else None,
                effects=None if args.effects is None else [e.strip() for e in args.effects.split(",") if e.strip()])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m flows.diagnose",
                                description="Trace the residual of a finished updating run to a missing effect, "
                                            "add it and update again.")
    p.add_argument("--run-id", required=True, metavar="ID")
    p.add_argument("--runs-dir", default="runs", metavar="PATH")
    p.add_argument("--measured", metavar="PATH", help="measured data (default: the run's)")
    p.add_argument("--n-jobs", type=int, help="parallel FE checks (default: the run's n_jobs)")
    add_closure_arguments(p)
    args = p.parse_args(argv)
    try:
        summary = diagnose(args.run_id, args.runs_dir, args.closure_name or "closure", args.measured,
                           n_jobs=args.n_jobs, **closure_options(args))
    except FileNotFoundError as exc:
        print(f"error: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except (DiagnoseError, MeasuredDataError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print_closure(summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
