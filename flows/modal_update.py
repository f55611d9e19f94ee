"""Updating on measured modes: ``python -m flows.update --measured MODES.uff`` (or ``.csv``) takes this path.

A measured file of modes (UFF dataset 55, or the modal CSV; :mod:`tasks.io.measured.modes`) is recognised by
:func:`route` before the FRF path reads it. The steps: read and match the modes to the model's test nodes,
check the band and that the paired modes are at least as many as the parameters, correlate at the nominal
model (``mac_before.png``), fit the parameters on the paired frequencies and scale-free shape residuals
(:mod:`fe_core.modal_update`: exact Nelson derivatives, trust-region Gauss-Newton from ``--starts``
points, MAC mode tracking each FE run), correlate at the result (``mac_after.png``), Laplace 95 % intervals.
The run folder ``<runs-dir>/<run-id>/`` gets ``modal_runs.jsonl`` (every FE run: parameters, frequencies),
``correlation_before.json``, ``correlation_after.json``, the pictures, ``summary.json`` and ``report.html``.

Uncertainties: ``--frequency-sigma`` (relative standard deviation of a measured frequency) and
``--shape-sigma`` (of a shape value, relative to the shape's RMS) weight the residuals. Stated ones give the
intervals as they are; when neither is stated, 0.002 and 0.02 set the relative weights and the common scale
is estimated from the residual (``chi^2 / (n - p)``), as the FRF update does without ``--noise``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import time
from pathlib import Path

import numpy as np

from prefect import flow

from flows.config import ConfigError, load_config
from strategies.modal_fit import LEAST_SQUARES_STATUS
from tasks.io.summary import SCHEMA_VERSION, interval_entries
from tasks.modal_stages import MODAL_STAGES

__all__ = ["route", "main", "run_modal_update", "modal_flow", "CLOSURE_EFFECTS"]

#: The effects the closure on modal residuals screens (fe_core.closure.effects names); --no-closure: none.
CLOSURE_EFFECTS = ("point_mass", "grounded_spring", "segment_mass")

DEFAULT_SIGMA_F = 0.002
DEFAULT_SIGMA_S = 0.02
#: Flags of the FRF path that mean nothing for modal data (ignored with a warning).
_FRF_ONLY = ("--trainer", "--lines", "--line-windows", "--residuals", "--emulate", "--polish")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m flows.update (modal data)",
                                description="Update the model's parameters on measured modes (docs/guide/modal-data.md).")
    p.add_argument("--config", metavar="PATH")
    p.add_argument("--model", metavar="NAME|PATH")
    p.add_argument("--measured", metavar="PATH", required=True)
    p.add_argument("--run-id", metavar="ID")
    p.add_argument("--runs-dir", metavar="PATH")
    p.add_argument("--seed", type=int)
    p.add_argument("--strategy", choices=("hybrid", "adaptive", "paper"),
                   help="hybrid (default): local least squares with Nelson Jacobians from --starts points; "
                        "adaptive (or paper): the paper's MRGP loop over the modal residuals, then that fit "
                        "from its best FE run")
    p.add_argument("--starts", type=int, default=3, help="local fits: the nominal model plus N-1 Latin points "
                                                         "(default 3)")
    p.add_argument("--frequency-sigma", type=float, metavar="S", help="relative std of a measured frequency")
    p.add_argument("--shape-sigma", type=float, metavar="S", help="std of a shape value over the shape's RMS")
    p.add_argument("--no-shapes", action="store_true", help="frequencies only")
    p.add_argument("--mac-threshold", type=float, default=0.6, help="lowest MAC of a pair (default 0.6)")
    p.add_argument("--identify-modes", metavar="LO-HI", help="FRF data: identify the modes between LO and HI Hz "
                   "with sdypy-EMA (LSCF/LSFD) and update on them")
    p.add_argument("--pol-order", type=int, default=40, help="highest LSCF polynomial order (default 40)")
    p.add_argument("--no-closure", action="store_true", help="no closure on the modal residual after the update")
    p.add_argument("--true-parameters", metavar="P1,P2,...", help="known parameters (synthetic data): the "
                                                                  "summary says which lie in their intervals")
    return p


def route(argv: list[str]) -> int | None:
    """Run the modal update when ``--measured`` (or the config's ``measured``) is a modal file; else None."""
    from tasks.io.measured.modes import is_modal_file

    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--measured")
    p.add_argument("--config")
    p.add_argument("--identify-modes")
    known, _ = p.parse_known_args(argv)
    if known.identify_modes is not None:
        return main(argv)
    try:
        config = load_config(known.config, measured=known.measured)
    except ConfigError:
        return None
    if not is_modal_file(config.resolve(config.measured)):
        return None
    if known.measured is None:
        argv = list(argv) + ["--measured", config.measured]
    return main(argv)


def main(argv: list[str]) -> int:
    from tasks.io.measured import MeasuredDataError

    args, rest = _parser().parse_known_args(argv)
    for flag in rest:
        if flag.startswith("-"):
            name = flag.split("=")[0]
            why = "applies to FRF data" if name in _FRF_ONLY else "is not an option of the modal update"
            print(f"warning: {name} {why}, ignored for modal data (docs/guide/modal-data.md)", file=sys.stderr)
    try:
        strategy = "adaptive" if args.strategy == "paper" else args.strategy
        config = load_config(args.config, measured=args.measured, model=args.model, run_id=args.run_id,
                             runs_dir=args.runs_dir, seed=args.seed, strategy=strategy)
        truth = None if args.true_parameters is None else [float(v) for v in args.true_parameters.split(",")]
        band = None
        if args.identify_modes is not None:
            from flows.config import parse_windows

            band = parse_windows(args.identify_modes)[0]
        summary = run_modal_update(config, args.starts, args.frequency_sigma, args.shape_sigma, args.no_shapes,
                                   args.mac_threshold, truth, band, args.pol_order,
                                   None if args.no_closure else CLOSURE_EFFECTS)
    except FileNotFoundError as exc:
        print(f"error: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except (ConfigError, MeasuredDataError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print_summary(summary)
    return 0


def run_modal_update(config, starts=3, sigma_f=None, sigma_s=None, no_shapes=False, threshold=0.6,
                     true_parameters=None, identify_band=None, pol_order=40, effects=CLOSURE_EFFECTS) -> dict:
    """Resolve the modal run (model, data, checks: nothing written when refused), then :func:`modal_flow`."""
    from flows import preflight
    from flows.problem import RESUMABLE_CHANGES, input_checksums, load_model
    from tasks import modal, modal_stages
    from tasks.runstore import RunStore

    stated = sigma_f is not None or sigma_s is not None
    sigma_f = DEFAULT_SIGMA_F if sigma_f is None else sigma_f
    sigma_s = None if no_shapes else (DEFAULT_SIGMA_S if sigma_s is None else sigma_s)
    if config.strategy == "conventional":
        raise ConfigError(f"{config.measured}: key 'strategy': 'conventional' (the paper's one-MRGP baseline) is "
                          "not offered for modal data; use 'hybrid' (local fits) or 'adaptive'/'paper' (the "
                          "paper's loop)")
    model, ref = load_model(config.model)
    names = model.parameter_names
    lower = np.maximum(np.full(model.n_parameters, config.lower), -0.95)
    upper = np.full(model.n_parameters, config.upper)
    if true_parameters is not None and len(true_parameters) != len(names):
        raise ConfigError(f"--true-parameters: {len(names)} values needed ({', '.join(names)})")
    if config.run_id is None:
        config = config.replace(run_id=f"modal-{dt.datetime.now(dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')}")
    paper = config.strategy == "adaptive"
    settings = {"kind": "modal update", "strategy": "paper" if paper else "gauss-newton",
                "starts": 1 if paper else starts, "sigma_f": sigma_f, "sigma_s": sigma_s,
                "stated": stated, "mac_threshold": threshold, "identify_modes": identify_band,
                "pol_order": pol_order, "closure_effects": None if effects is None else list(effects)}
    folder = config.resolve(config.runs_dir) / config.run_id
    inputs = input_checksums(config, ref)
    resuming = (folder / "manifest.json").exists()
    if resuming:
        preflight.check_resume(config, folder, RESUMABLE_CHANGES, inputs)
        _check_settings(folder, settings)
    measured = config.resolve(config.measured)
    identified, stabilisation, seconds_identify = None, None, 0.0
    if identify_band is not None:
        from tasks.io.measured import read_measured
        from tasks.modal_identify import identify_modes

        t0 = time.perf_counter()
        identified, stabilisation = identify_modes(read_measured(measured), identify_band[0], identify_band[1],
                                                   pol_order)
        seconds_identify = time.perf_counter() - t0
    # a resumed run with the same inputs (checked above) passed the band check when it started
    data, n_model = modal.load_modal_data(measured, model, float(upper.max()), identified, check=not resuming)
    residual = modal.modal_residual(data, model, n_model, sigma_f, sigma_s, threshold)
    store = RunStore(folder)
    notes = modal_stages.identifiable_notes(store, residual, names, str(measured))
    manifest = {"run_id": config.run_id, "created": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
                "record_version": preflight.RECORD_VERSION, "config": config.to_dict(), "modal": settings,
                "stages": list(modal_stages.MODAL_STAGES), **inputs}
    if resuming:
        manifest = {**store.read_manifest(), "resumed": manifest["created"]}
    folder.mkdir(parents=True, exist_ok=True)
    store.write_manifest(manifest)
    notes = modal_stages.record_identifiable(store, notes)
    job = ModalJob(config, model, data, residual, n_model, names, lower, upper, stated, settings, notes)
    summary = modal_flow(job, true_parameters, identified, stabilisation, seconds_identify)
    return summary


class ModalJob:
    """What the flow of one modal run works on (resolved by :func:`run_modal_update`)."""

    def __init__(self, config, model, data, residual, n_model, names, lower, upper, stated, settings, notes):
        self.config, self.model, self.data, self.residual = config, model, data, residual
        self.n_model, self.names, self.lower, self.upper = n_model, names, lower, upper
        self.stated, self.settings, self.notes = stated, settings, notes

    def __repr__(self) -> str:  # how the flow's parameter shows in the Prefect UI
        return f"ModalJob({self.config.run_id}: {self.config.measured} on {self.config.model})"


def _check_settings(folder: Path, settings: dict) -> None:
    """A modal run resumes only with the settings it was started with (as check_resume for the config)."""
    import json

    manifest = folder / "manifest.json"
    old = json.loads(manifest.read_text()).get("modal")
    if old is None:
        raise ConfigError(f"{manifest}: run {folder.name!r} is not a modal update; choose a new --run-id")
    now = json.loads(json.dumps(settings))
    changed = [f"setting {k} ({old.get(k)!r} then, {now[k]!r} now)" for k in now if old.get(k) != now[k]]
    if changed:
        raise ConfigError(f"{manifest}: run {folder.name!r} was started with other inputs: {'; '.join(changed)}. "
                          f"Its stored results belong to those; resume with the same inputs, or start a new run "
                          f"with another --run-id (e.g. {folder.name}-2)")


@flow(name="modal-update", flow_run_name="modal-{job.config.run_id}", log_prints=True)
def modal_flow(job: "ModalJob", true_parameters=None, identified=None, stabilisation=None,
               seconds_identify: float = 0.0) -> dict:
    """The stages of one modal run (:mod:`tasks.modal_stages`), then its summary and report."""
    from tasks import modal, modal_stages

    t0 = time.perf_counter()
    config, model, data, residual, names = job.config, job.model, job.data, job.residual, job.names
    folder = config.resolve(config.runs_dir) / config.run_id
    root = str(folder)
    threshold = job.settings["mac_threshold"]
    if identified is not None:  # UFF55 needs test DOFs NODE:DIR; channels named as sensors go to a table
        from tasks.io.measured.frf import parse_dof
        from tasks.io.measured.modes import write_csv, write_uff55

        if all(parse_dof(d) is not None for d in identified.dofs):
            write_uff55(folder / "identified_modes.uff", identified)
        else:
            write_csv(folder / "identified_modes.csv", identified)
    before = modal_stages.correlation_task(root, "correlation_before", data, model, np.zeros(len(names)),
                                           job.n_model, threshold)
    modal.write_json(folder / "correlation_before.json", before)
    modal.mac_figure(before, folder / "mac_before.png", "MAC before the update (nominal model)")
    x0, paper = None, None
    if job.settings.get("strategy") == "paper":
        paper = modal_stages.paper_task(root, residual, job.lower, job.upper, paper_options(config))
        x0 = paper["best"]
    fit = modal_stages.fit_task(root, residual, job.lower, job.upper, job.settings["starts"], config.seed, job.stated,
                                x0)
    theta = np.asarray(fit["theta"], float)
    after = modal_stages.correlation_task(root, "correlation_after", data, model, theta, job.n_model, threshold)
    modal.write_json(folder / "correlation_after.json", after)
    modal.mac_figure(after, folder / "mac_after.png", "MAC after the update")
    if not (folder / "shapes_after.png").exists():  # drawn from the model's modes at theta (an eigen-solve)
        modal.shapes_figure(data, model, theta, after, folder / "shapes_after.png")
    closure = None
    if job.settings["closure_effects"]:
        closure = modal_stages.closure_task(root, residual, theta, job.lower, job.upper, job.stated,
                                            job.settings["closure_effects"], fit["active"])
    summary = modal_summary(job, fit, closure, true_parameters)
    if paper is not None:
        summary["paper_loop"] = paper
        summary["fe_runs_fit"] = fit["fe_runs"] - paper["fe_runs_computed"]
        summary["stop_reason"] = f"paper loop: {paper['reason']}; then {summary['stop_reason']}"
    if identified is not None:
        summary.update(identified_from=config.measured, identification_band_hz=list(job.settings["identify_modes"]),
                       stabilisation=stabilisation, seconds_identification=seconds_identify)
    summary["wall_seconds"] = round(time.perf_counter() - t0 + seconds_identify, 3)
    modal.write_json(folder / "summary.json", summary)
    from tasks.modal_report import write_report

    write_report(folder, summary)
    return summary


def paper_options(config):
    """The paper loop's settings from the config (Table 2: q, s, z, w, budgets, trainer, outputs, seed)."""
    from strategies.paper import PaperOptions

    return PaperOptions(q=config.q, s=config.s, z=config.z, w=config.w, max_iterations=config.max_iterations,
                        max_fe=config.max_fe_evaluations, min_distance_factor=config.min_distance_factor,
                        std_floor=config.std_floor, trainer=config.trainer, outputs=config.outputs,
                        emulate="errors", seed=config.seed)


def modal_summary(job, fit: dict, closure: dict | None, true_parameters) -> dict:
    """``summary.json`` of a modal run from its stages' results."""
    config, names, m, residual = job.config, job.names, job.data.modes, job.residual
    folder = config.resolve(config.runs_dir) / config.run_id
    sd, lo95, hi95 = (np.asarray(fit[k], float) for k in ("sd", "lower95", "upper95"))
    pairing = fit["pairing"]
    paired = [{"test": m.names[t], "model": f"model mode {j + 1}", "f_test_hz": float(m.frequencies_hz[t]),
               "f_model_hz": float(f), "mac": float(v)}
              for t, j, f, v in zip(pairing["test"], pairing["model"], pairing["f_model"], pairing["mac"])]
    missing = [name for k, name in enumerate(m.names) if k not in set(pairing["test"])]
    numbers = [int(n.split()[-1]) for n in m.names if n.split()[-1].isdigit()]
    gaps = sorted(set(range(1, max(numbers) + 1)) - set(numbers)) if numbers else []
    s = job.settings
    best = min(fit["starts"], key=lambda r: r["cost"])  # the start the fit kept (least cost)
    summary = {
        "schema_version": SCHEMA_VERSION, "kind": "modal", "run_id": config.run_id, "run_folder": str(folder),
        "strategy": config.strategy, "seed": config.seed,
        "parameters": {n: float(v) for n, v in zip(names, fit["theta"])},
        "intervals": interval_entries(names, lo95, hi95, sd), "covariance": fit["covariance"],
        "interval_method": "laplace", "fe_evaluations": fit["fe_runs"], "jacobians": fit["jacobians"],
        "converged": best["status"] > 0,
        "stop_reason": f"local least squares from {len(fit['starts'])} start(s); the best start: "
                       f"{LEAST_SQUARES_STATUS.get(best['status'], 'scipy status ' + str(best['status']))}",
        "model": config.model, "measured": config.measured,
        "residual": "paired frequencies (f_model - f_test) / (sigma_f f_test) and shape differences u - MSF psi "
                    "of unit-norm measured shapes (|.|^2 = 1 - MAC) / (sigma_s / sqrt(n_dofs))",
        "sigma_f": s["sigma_f"], "sigma_s": s["sigma_s"],
        "uncertainties": "stated" if job.stated else "estimated from the residual",
        "chi2": fit["chi2"], "n_residuals": fit["n_residuals"],
        "n_parameters": len(names), "scale2": fit["scale2"], "paired_modes": paired,
        "unpaired_measured": sorted(set(missing + list(fit["unpaired"])), key=m.names.index),
        "left_out": [m.names[k] for k in range(m.n_modes) if k not in set(fit["active"])],
        "missing_mode_numbers": [f"mode {k}" for k in gaps],
        "seconds": fit["seconds"], "starts": fit["starts"],
        "mode_swaps": fit["swaps"], "n_test_dofs": len(m.dofs), "notes": list(m.notes) + list(job.notes),
        "stages": list(MODAL_STAGES),
    }
    wide = [n for n, a, b, lo, hi in zip(names, lo95, hi95, job.lower, job.upper) if b - a > hi - lo]
    if wide:  # e.g. frequencies alone on a symmetric structure: mirror segments trade off
        summary["not_determined"] = wide
        summary["notes"] = summary["notes"] + [f"not determined by these data (95 % interval wider than the search "
                                               f"box): {', '.join(wide)}"]
    if closure is not None:
        summary["closure"] = closure
    if true_parameters is not None:
        t = np.asarray(true_parameters, float)
        summary["true_parameters"] = dict(zip(names, t.tolist()))
        summary["parameter_errors"] = dict(zip(names, np.abs(np.asarray(fit["theta"], float) - t).tolist()))
        summary["intervals_contain_truth"] = dict(zip(names, ((lo95 <= t) & (t <= hi95)).tolist()))
    return summary


def print_summary(summary: dict) -> None:
    print(f"modal update {summary['run_id']}: {len(summary['paired_modes'])} paired modes at "
          f"{summary['n_test_dofs']} test DOFs; {summary['fe_evaluations']} FE runs ({summary['jacobians']} with "
          f"Nelson derivatives), {summary['seconds']:.1f} s; chi2 {summary['chi2']:.1f} for {summary['n_residuals']} "
          f"residuals ({summary['uncertainties']})")
    if "paper_loop" in summary:
        pl = summary["paper_loop"]
        print(f"  paper loop (MRGP over the modal residuals): {pl['reason']}; {pl['iterations']} iterations, "
              f"{pl['fe_runs']} FE runs in {pl['seconds']:.1f} s, best mean |r| {pl['best_error']:.3f} (noise threshold "
              f"{pl['threshold']:.3f}); then the local fit from its best: {summary['fe_runs_fit']} FE runs")
    if "stabilisation" in summary:
        st = summary["stabilisation"]
        print(f"  modes identified from {summary['identified_from']} ({summary['seconds_identification']:.1f} s): "
              + "; ".join(n for n in summary["notes"] if "identified by" in n)
              + (f"; peaks without a stable pole dropped: {st['dropped_peaks_hz']} Hz" if st["dropped_peaks_hz"]
                 else ""))
    inside = summary.get("intervals_contain_truth")
    for name, value in summary["parameters"].items():
        iv = summary["intervals"][name]
        flag = "" if inside is None else "  (true value inside)" if inside[name] else "  (true value OUTSIDE)"
        print(f"  {name:<10} {value:+.4f}  sd {iv['sd']:.4f}  95 % [{iv['lower95']:+.4f}, {iv['upper95']:+.4f}]{flag}")
    for p in summary["paired_modes"]:
        print(f"  {p['test']:<8} {p['f_test_hz']:9.3f} Hz <-> {p['model']:<14} {p['f_model_hz']:9.3f} Hz  "
              f"MAC {p['mac']:.3f}")
    if summary["missing_mode_numbers"]:
        print(f"  missing from the measured modes: {', '.join(summary['missing_mode_numbers'])}")
    if summary["unpaired_measured"]:
        print(f"  unpaired measured modes: {', '.join(summary['unpaired_measured'])}")
    if summary["left_out"]:
        print(f"  left out of the update (unpaired at the nominal model): {', '.join(summary['left_out'])}")
    if summary.get("not_determined"):
        print(f"  warning: not determined by these data (95 % interval wider than the box): "
              f"{', '.join(summary['not_determined'])}")
    if summary["mode_swaps"]:
        print(f"  mode swaps tracked: {'; '.join(summary['mode_swaps'])}")
    if "closure" in summary:
        c = summary["closure"]
        line = f"  closure on the modal residual: {c['verdict']} (chi2 {c['before']['chi2']:.1f} for {c['before']['dof']} dof"
        if c["chosen"] is not None:
            line += "; " + " + ".join(f"{ch['effect']} at {ch['location']} {ch['value']:.4g} {ch['unit']} "
                                      f"(sd {ch['sd']:.2g})" for ch in c.get("added") or [c["chosen"]])
            line += f": chi2 {c['after']['chi2']:.1f} for {c['after']['dof']} dof"
        print(line + f"; {c['fe_runs']} FE runs)")
    print(f"  written to {summary['run_folder']} (summary.json, report.html)")
