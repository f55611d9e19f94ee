"""FE model updating as a Prefect flow: ``python -m flows.update``.

The default strategy, ``hybrid`` (:mod:`strategies.hybrid`), runs Gauss-Newton from
the nominal model and goes global (MRGP emulator, parallel starts) only when
what is left is not noise; each cycle is a subflow ``cycle-<k>``. The paper's
adaptive MRGP loop (``--strategy adaptive``): each iteration is a subflow run
named ``iteration-<k>`` with the tasks
``fe -> distribution -> train -> predict -> select`` (:mod:`strategies.paper`),
then the polish. Every strategy runs under one driver (:mod:`flows.drive`,
:mod:`tasks.driver`). Everything is written under
``runs/<run-id>/``; running again with the same ``--run-id`` resumes
where the last run stopped. The path of one run: config (:mod:`flows.config`) ->
problem (:mod:`flows.problem`) -> strategy (:mod:`strategies.registry`) under the
driver -> stages -> run folder -> summary (:mod:`flows.run`, :mod:`flows.summary`).

Examples::

    python -m flows.update                                  # benchmark, hybrid strategy
    python -m flows.update --strategy adaptive --no-polish  # the paper's loop, Table 2
    python -m flows.update --trainer pso --seed 3 --run-id pso-3
    python -m flows.update --strategy conventional
    python -m flows.update --repeats 5
    python -m flows.update rerun --run-id pso-3 --iteration 3 --stage train --trainer sao
    python -m flows.update rerun --run-id my-run --stage check --noise 0.01

With no Prefect server configured (no ``PREFECT_API_URL``), Prefect starts a
temporary local API for the run; nothing leaves the machine.
"""

from __future__ import annotations

from flows import environment  # noqa: F401  (first: the environment Prefect starts in)

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from prefect import flow  # noqa: E402

from flows import problem as problems  # noqa: E402
from flows.config import (TRAINERS, ConfigError, UpdateConfig, add_setting_flags, load_config,  # noqa: E402
                          settings_from_args)
from flows.local_api import start_early  # noqa: E402
from flows.rerun import rerun_stage, rerunnable  # noqa: E402
from flows.run import run_update  # noqa: E402
from flows.summary import print_summary  # noqa: E402
from strategies import registry  # noqa: E402
from tasks.io.measured import MeasuredDataError, read_measured  # noqa: E402
from tasks.runlock import RunLock, RunLockedError  # noqa: E402

__all__ = ["update_flow", "run_update", "main", "rerun_stage", "print_summary"]

#: Measurements of the benchmark at the SPEC's actual alpha: their runs report parameter errors.
BENCHMARK_MEASUREMENTS = ("data/benchmark/measured.csv", "data/benchmark/hammer.uff",
                          "data/examples/hammer_records/hammer_records.uff", "data/examples/hammer_tests/roving.uff",
                          "data/examples/hammer_tests/mobility.uff")


@flow(name="mrgp-update", flow_run_name="update-{config.run_id}", log_prints=True)
def update_flow(config: UpdateConfig, problem=None) -> dict:
    """The whole updating run (all repeats); returns the summary written to ``summary.json``.

    ``problem``: the run's :class:`tasks.problem.Problem` when the caller resolved it already
    (:func:`flows.problem.resolve`), else resolved here."""
    return run_update(config, problem)


# -- command line -------------------------------------------------------------------------------
def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m flows.update",
        description="Update the FE model's segment parameters from measured FRF amplitudes "
                    "(adaptive MRGP, Zhou & Tang). Subcommand 'rerun' recomputes one stage of an earlier run.",
        epilog="Settings come from the defaults, then --config, then these flags. See data/update.example.toml. "
               "Measured modes (UFF dataset 55 or a modal CSV), or FRFs with --identify-modes LO-HI, take the modal "
               "update, with its own options --frequency-sigma, --shape-sigma, --no-shapes, --mac-threshold, "
               "--identify-modes, --pol-order, --starts, --true-parameters (docs/guide/modal-data.md).",
    )
    p.add_argument("--config", metavar="PATH", help="TOML file with any of the settings (data/update.example.toml)")
    add_setting_flags(p)  # one flag per setting, from their declarations (flows/config.py, strategies/registry.py)
    from flows.diagnose import add_closure_arguments

    p.add_argument("--close-loop", action="store_true",
                   help="after the update, trace the residual to a missing effect, add it and update again "
                        "(python -m flows.diagnose on this run; writes <run folder>/closure/)")
    add_closure_arguments(p, noise=False)  # --noise is a setting of the run (above)
    return p


def _rerun_parser() -> argparse.ArgumentParser:
    stages = {name: rerunnable(name) for name in registry.names()}
    p = argparse.ArgumentParser(prog="python -m flows.update rerun",
                                description="Recompute one stage of an earlier run from its stored inputs, into a new "
                                            "folder beside the original. Stages: " + "; ".join(
                                                f"{', '.join(v)} ({k})" for k, v in stages.items()) + ".")
    p.add_argument("--run-id", required=True, metavar="ID", help="the run (a repeat of a --repeats run: ID/repeat=0)")
    p.add_argument("--runs-dir", default="runs", metavar="PATH")
    p.add_argument("--iteration", type=int, default=1, help="the iteration (cycle of the hybrid) of the stage "
                                                            "(default 1)")
    p.add_argument("--stage", required=True, choices=sorted({s for v in stages.values() for s in v}))
    p.add_argument("--trainer", choices=TRAINERS, help="MRGP trainer for train or global (default: the run's)")
    p.add_argument("--noise", type=float, metavar="SIGMA",
                   help="relative noise of the measured amplitudes for check or intervals (default: the run's)")
    p.add_argument("--posterior-fe", type=int, metavar="N", help="FE runs of the sampled posterior (intervals)")
    return p


def main(argv: list[str] | None = None) -> int:
    started = time.monotonic()  # --close-loop's closure gets what is left of the command's 15 minutes
    argv = sys.argv[1:] if argv is None else argv
    if not (argv and argv[0] == "rerun"):
        from flows.modal_update import route  # a file of measured modes takes the modal path

        routed = route(argv)
        if routed is not None:
            return routed
    try:
        if argv and argv[0] == "rerun":
            args = _rerun_parser().parse_args(argv[1:])
            root = Path(args.runs_dir)
            root = root if root.is_absolute() else Path(__file__).resolve().parents[1] / root
            out = rerun_stage(root / args.run_id, args.iteration, args.stage, args.trainer, args.noise,
                              args.posterior_fe)
            print(f"rerun written to {out}")
            return 0
        args = _run_parser().parse_args(argv)
        config = load_config(args.config, **settings_from_args(args))
        if config.run_id is None:
            stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
            config = config.replace(run_id=f"{config.strategy}-{config.trainer}-seed{config.seed}-{stamp}")
        if config.measured in BENCHMARK_MEASUREMENTS and config.true_parameters is None:
            from fe_core.benchmark import ALPHA_ACTUAL

            config = config.replace(true_parameters=ALPHA_ACTUAL.tolist())
        # refuse bad data before any work; the file is read once
        measured = read_measured(config.resolve(config.measured), averages=config.averages)
    except FileNotFoundError as exc:
        print(f"error: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except (ConfigError, MeasuredDataError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    local_api = start_early()  # Prefect's temporary API starts beside the model's reading (flows/local_api.py)
    try:
        # Refuse bad inputs, a run in use, or a full / read-only disk before any work.
        problem = problems.resolve(config, measured)
        if args.close_loop:
            from flows.diagnose import MASS_FACTORS_REFUSED

            gammas = [n for n in problem.names if n.startswith("gamma_")]
            if gammas:
                raise ConfigError(f"--close-loop: {config.model}: "
                                  f"{MASS_FACTORS_REFUSED.format(names=', '.join(gammas))}")
        lock = RunLock(config.resolve(config.runs_dir) / config.run_id).acquire()
        if lock.stale_owner:
            owner = lock.stale_owner
            print(f"warning: {lock.path}: stale lock of pid {owner.get('pid')} on host {owner.get('host')}, which "
                  "no longer runs; taken over, resuming", file=sys.stderr)
    except (ConfigError, MeasuredDataError, RunLockedError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        local_api.abandon()
        return 2
    except OSError as exc:
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        local_api.abandon()
        return 2
    except BaseException:  # an interrupt, an unexpected error: the server started for the flow goes too
        local_api.abandon()
        raise
    try:
        for line in problem.model.placements:  # where the sensor and excitation points landed
            print(f"model: {line}")
        local_api.wait()
        summary = update_flow(config, problem)
    finally:
        lock.release()
    print_summary(summary)
    if args.close_loop:
        from flows.diagnose import DiagnoseError, closure_minutes_left, closure_options, diagnose, print_closure

        options = closure_options(args)
        release_update_solvers(problem.model)
        if options["max_minutes"] is None:
            options["max_minutes"] = closure_minutes_left(time.monotonic() - started)
            print(f"closure: time limit {options['max_minutes']:g} min (what is left of 15 min since the command "
                  "began, less half a minute for the command's end, at least 5; --closure-minutes sets it)")
        try:
            closure = diagnose(config.run_id, config.runs_dir, args.closure_name or "closure", problem=problem,
                               **options)
        except (DiagnoseError, MeasuredDataError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print_closure(closure)
    return 0


def release_update_solvers(model) -> None:
    """Free what the update's FE runs kept in this process before the closure starts: PARDISO's idle factors, the
    recycled Krylov spaces and the global reduced basis of the Gauss-Newton rounds (at 500k DOFs a factor of
    2-4 GB and a basis of up to 1.5 GB; the closure builds reduced models of its own)."""
    from fe_core.solvers import pardiso, recycle, reduced_basis

    pardiso.release_idle(0)
    recycle.forget(model)
    reduced_basis.forget(model)


if __name__ == "__main__":
    raise SystemExit(main())
