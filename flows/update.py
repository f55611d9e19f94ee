"""FE model updating as a Prefect flow: ``python -m flows.update``.

The default strategy, ``hybrid`` (:mod:`flows.hybrid`), runs Gauss-Newton from
the nominal model and goes global (MRGP emulator, parallel starts) only when
what is left is not noise; each cycle is a subflow ``cycle-<k>``. The paper's
adaptive MRGP loop (``--strategy adaptive``): each iteration is a subflow run
named ``iteration-<k>`` with the tasks
``samples -> fe -> errors -> distribution -> train -> predict -> select``
(see :mod:`tasks.paper`). Everything is written under
``runs/<run-id>/``; running again with the same ``--run-id`` resumes
where the last run stopped. The path of one run: config -> problem
(:mod:`flows.problem`) -> strategy (:mod:`flows.hybrid`, :mod:`flows.paper`) ->
stages -> run folder -> summary (:mod:`flows.run`, :mod:`flows.summary`).

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
from pathlib import Path  # noqa: E402

from prefect import flow  # noqa: E402

from flows import problem as problems  # noqa: E402
from flows.config import (EMULATES, LINES, OUTPUTS, RESIDUALS, STRATEGIES, TRAINERS, ConfigError,  # noqa: E402
                          UpdateConfig, load_config, parse_windows)
from flows.rerun import rerun_stage  # noqa: E402
from flows.run import run_update  # noqa: E402
from flows.summary import print_summary  # noqa: E402
from tasks import fe_backends  # noqa: E402
from tasks.io.measured import MeasuredDataError, read_measured  # noqa: E402
from tasks.runlock import RunLock, RunLockedError  # noqa: E402

__all__ = ["update_flow", "run_update", "main", "rerun_stage", "print_summary"]

#: Measurements of the benchmark at the SPEC's actual alpha: their runs report parameter errors.
BENCHMARK_MEASUREMENTS = ("data/benchmark/measured.csv", "data/benchmark/hammer.uff")


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
               "--identify-modes, --pol-order, --starts, --true-parameters (docs/modal-data.md).",
    )
    p.add_argument("--config", metavar="PATH", help="TOML file with any of the settings (data/update.example.toml)")
    p.add_argument("--model", metavar="NAME|PATH", help="FE model: three_plate (default, the benchmark) or a "
                                                       "model file model.toml (docs/model-files.md)")
    p.add_argument("--measured", metavar="PATH", help="measured FRFs: .csv, .parquet or .uff (docs/measured-formats.md) "
                                                      "(default data/benchmark/measured.csv)")
    p.add_argument("--run-id", metavar="ID", help="run folder name under runs; an existing id resumes that run")
    p.add_argument("--runs-dir", metavar="PATH", help="where run folders go (default runs)")
    p.add_argument("--trainer", choices=TRAINERS, help="MRGP hyper-parameter trainer (default gradient)")
    p.add_argument("--strategy", choices=STRATEGIES,
                   help="hybrid (default: Gauss-Newton from the nominal model, global with the MRGP emulator when "
                        "the residual is not noise), adaptive (the paper's MRGP loop; with --no-polish exactly "
                        "the paper's procedure) or conventional (the paper's 300-sample baseline)")
    p.add_argument("--seed", type=int, help="master random seed (default 0)")
    p.add_argument("--n-jobs", type=int, help="parallel FE processes, -1 = all cores (default 2)")
    p.add_argument("--fe-backend", choices=fe_backends.FE_BACKENDS,
                   help="where FE runs execute: loky processes here (default) or a Dask cluster")
    p.add_argument("--dask-address", metavar="ADDR",
                   help="Dask scheduler for --fe-backend dask, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--repeats", type=int, help="independent runs with seeds seed..seed+N-1 (default 1)")
    p.add_argument("--threshold", type=float, help="stop at this overall error, e.g. 0.01 = 1 %% (default)")
    p.add_argument("--max-iterations", type=int, help="iteration budget (default 12)")
    p.add_argument("--max-fe-evaluations", type=int, help="FE-run budget (default 240)")
    p.add_argument("-q", type=int, help="initial uniform samples (default 20)")
    p.add_argument("-w", type=int, help="candidates predicted per iteration (default 10000)")
    p.add_argument("-s", type=int, help="FE runs per iteration (default 20)")
    p.add_argument("-z", type=int, help="best samples defining the sampling distribution (default 20)")
    p.add_argument("--emulate", choices=EMULATES,
                   help="what the paper loop's MRGP emulates: modes (default: the lowest modes of each FE run and "
                        "the rest of its receptance; the error of a candidate computed from them) or errors (the "
                        "paper's relative residuals)")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="after the MRGP loop, least squares on the FE model from the best sample (default on)")
    p.add_argument("--polish-max-fe", type=int, metavar="N",
                   help="FE runs reserved for the polish out of --max-fe-evaluations "
                        "(default 200: the loop hands over after 2 iterations)")
    p.add_argument("--polish-target", type=float, metavar="E",
                   help="overall error at which the polish stops (default 1e-4 = 0.01 %%)")
    p.add_argument("--polish-stall-rtol", type=float, metavar="R",
                   help="the polish also stops when its error improved by less than R (relative) over its last "
                        "3 Jacobians, e.g. at the noise of real data (default 0.01; 0 = off)")
    p.add_argument("--outputs", choices=OUTPUTS,
                   help="MRGP over all k responses (full), in a reduced output basis (reduced), or auto "
                        "(default: reduced when k > 200)")
    p.add_argument("--lines", choices=LINES,
                   help="measured lines that enter the update: all (default), those in --line-windows, or windows "
                        "around the measured resonances (half-power band x --resonance-widen)")
    p.add_argument("--line-windows", metavar="LO-HI[,LO-HI...]",
                   help="frequency windows in Hz for --lines windows, e.g. 100-120,280-300")
    p.add_argument("--resonance-widen", type=float, metavar="F",
                   help="factor on each resonance's half-power band for --lines resonances (default 2)")
    p.add_argument("--min-coherence", type=float, metavar="C",
                   help="leave out measured values whose coherence is below C (default 0.9)")
    p.add_argument("--averages", type=int, metavar="N",
                   help="the number of averages (hits) behind the measured FRFs and coherence where the file does "
                        "not say (UFF58 ID lines, a table's averages); with the coherence it sets the noise per line")
    p.add_argument("--residuals", choices=RESIDUALS,
                   help="amplitude residuals (Eq. 5), complex ones (real and imaginary parts of (Z - H)/|H|), or auto "
                        "(default: complex when the data carry phase, except the legacy sensor form)")
    p.add_argument("--intervals", action=argparse.BooleanOptionalAction, default=None,
                   help="after the polish, 95 %% intervals and the covariance of the parameters (default on; "
                        "their noise level: --noise, else estimated from the residual)")
    p.add_argument("--posterior-fe", type=int, metavar="N",
                   help="FE runs of the sampled posterior used instead of the Laplace intervals where their "
                        "linearisation fails its check (a bound, a curved valley); 0 = never (default 400)")
    from flows.diagnose import add_closure_arguments  # --noise, also the 95 % parameter intervals' noise level

    p.add_argument("--close-loop", action="store_true",
                   help="after the update, trace the residual to a missing effect, add it and update again "
                        "(python -m flows.diagnose on this run; writes <run folder>/closure/)")
    add_closure_arguments(p)
    return p


def _rerun_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m flows.update rerun",
                                description="Recompute one stage of an earlier run from its stored inputs, into a new "
                                            "folder beside the original. Stages: train, predict, intervals (the "
                                            "paper's loop); local, global, check, intervals (the hybrid).")
    p.add_argument("--run-id", required=True, metavar="ID", help="the run (a repeat of a --repeats run: ID/repeat=0)")
    p.add_argument("--runs-dir", default="runs", metavar="PATH")
    p.add_argument("--iteration", type=int, default=1, help="the iteration (cycle of the hybrid) of the stage "
                                                            "(default 1)")
    p.add_argument("--stage", required=True, choices=sorted({"train", "predict", "local", "global", "check",
                                                             "intervals"}))
    p.add_argument("--trainer", choices=TRAINERS, help="MRGP trainer for train or global (default: the run's)")
    p.add_argument("--noise", type=float, metavar="SIGMA",
                   help="relative noise of the measured amplitudes for check or intervals (default: the run's)")
    p.add_argument("--posterior-fe", type=int, metavar="N", help="FE runs of the sampled posterior (intervals)")
    return p


def main(argv: list[str] | None = None) -> int:
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
        config = load_config(
            args.config, measured=args.measured, run_id=args.run_id, runs_dir=args.runs_dir, trainer=args.trainer,
            strategy=args.strategy, seed=args.seed, n_jobs=args.n_jobs, fe_backend=args.fe_backend,
            dask_address=args.dask_address, repeats=args.repeats,
            threshold=args.threshold, max_iterations=args.max_iterations,
            max_fe_evaluations=args.max_fe_evaluations, q=args.q, w=args.w, s=args.s, z=args.z,
            polish=args.polish, polish_max_fe=args.polish_max_fe, polish_target=args.polish_target,
            emulate=args.emulate,
            polish_stall_rtol=args.polish_stall_rtol, model=args.model, outputs=args.outputs,
            intervals=args.intervals, noise=args.noise, posterior_fe=args.posterior_fe, lines=args.lines,
            line_windows=None if args.line_windows is None else parse_windows(args.line_windows),
            resonance_widen=args.resonance_widen, min_coherence=args.min_coherence, residuals=args.residuals,
            averages=args.averages,
        )
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
        return 2
    except OSError as exc:
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    try:
        for line in problem.model.placements:  # where the sensor and excitation points landed
            print(f"model: {line}")
        summary = update_flow(config, problem)
    finally:
        lock.release()
    print_summary(summary)
    if args.close_loop:
        from flows.diagnose import DiagnoseError, closure_options, diagnose, print_closure

        try:
            closure = diagnose(config.run_id, config.runs_dir, args.closure_name or "closure", problem=problem,
                               **closure_options(args))
        except (DiagnoseError, MeasuredDataError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print_closure(closure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
