"""Wall time of the closure on the 34k-DOF tet10 bracket with ~750 lines (issue 28), by stage, with counts.

    python -m benchmarks.make.bracket_mass                       # the data, once
    nice -n 10 python -m benchmarks.closure_speed                # the closure as fe_core.closure.close_loop runs it
    nice -n 10 python -m benchmarks.closure_speed --profile out.prof --restarts 0
    nice -n 10 python -m benchmarks.closure_speed --max-effects 3 --trace fits.jsonl  # full evaluations by stage

The closure starts from the true factors (what a good update returns; the flow's ``--close-loop`` starts
from the update's result). It prints the wall and CPU time of the baseline (alpha-only fit and restarts),
the screens and the checks, how many sparse factorisations of K and Krylov spaces were made and what they
cost, and the outcome (effect, node, mass). ``--path plain`` is the solver path before issue 28 (:mod:`fe_core.solvers.pardiso` off).
"""

from __future__ import annotations

import os

# One BLAS / OpenMP / MKL thread, as the flow runs (flows/environment.py): threaded BLAS on the reduced
# model's small matrices spins on 2 busy cores (a 140 x 140 eigenproblem: 74 ms CPU against 3.7 ms).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parents[1] / "data" / "examples" / "bracket"


class Counter:
    """Wraps a module function, counting its calls and their wall time."""

    def __init__(self, module, name):
        self.module, self.name, self.calls, self.seconds = module, name, 0, 0.0
        self.original = getattr(module, name)

        def wrapped(*args, **kwargs):
            t = time.perf_counter()
            try:
                return self.original(*args, **kwargs)
            finally:
                self.calls += 1
                self.seconds += time.perf_counter() - t

        setattr(module, name, wrapped)

    def __str__(self):
        return f"{self.name}: {self.calls} calls, {self.seconds:.1f} s"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.closure_speed", description=__doc__.split("\n\n")[0])
    p.add_argument("--measured", default=str(HERE / "measured_mass.csv"))
    p.add_argument("--model", default=str(HERE / "model.toml"))
    p.add_argument("--restarts", type=int, default=8, help="baseline restarts (the flow's default: 8)")
    p.add_argument("--max-effects", type=int, default=1)
    p.add_argument("--per-type", type=int, default=1, help="the flow's default: 1")
    p.add_argument("--effects", default=None, help="comma-separated effect kinds (default: the whole library)")
    p.add_argument("--path", choices=("fast", "pardiso", "plain"), default="fast",
                   help="fast: PARDISO reuse and the fits on the growing reduced model (fe_core.closure.fast); "
                        "pardiso: the reuse only; plain: as before issue 28")
    p.add_argument("--stages", action="store_true",
                   help="only the alpha-only fit, the screen and the point mass's fit, timed")
    p.add_argument("--check", action="store_true", help="with --stages: the point mass's check with its moves too")
    p.add_argument("--profile", metavar="FILE", help="write cProfile stats and print the top 25 by cumulative time")
    p.add_argument("--json", metavar="FILE", help="append the result as a JSON line")
    p.add_argument("--trace", metavar="FILE", help="with --path fast: every fit and full evaluation with its stage "
                                                   "(JSON lines), and a table of full evaluations by stage")
    args = p.parse_args(argv)

    from fe_core.closure.loop import close_loop
    from fe_core.closure.effects import build_library
    from fe_core.solvers import adjoint, frf
    from flows.problem import load_model
    from tasks.io.measured import read_measured

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    model = load_model(args.model)[0]
    measured = read_measured(args.measured)
    truth = json.loads((HERE / "truth_mass.json").read_text())
    freqs, u = measured.frequencies_hz, measured.amplitude
    library = build_library(model)
    if args.effects:
        kinds = {k.strip() for k in args.effects.split(",")}
        library = [e for e in library if e.kind in kinds]
    from fe_core.solvers import pardiso

    pardiso.ENABLED = args.path in ("fast", "pardiso")
    counters = [Counter(frf, "spd_solver"), Counter(adjoint, "krylov_space")]
    print(f"model: {model.n_dofs if hasattr(model, 'n_dofs') else '?'} DOFs; {freqs.size} lines x {u.shape[1]} "
          f"sensors = {u.size} values; {len(library)} effect kinds; path {args.path}; restarts {args.restarts}")
    prof = cProfile.Profile() if args.profile else None
    t0, c0 = time.perf_counter(), time.process_time()
    if prof:
        prof.enable()
    from fe_core.closure import fast

    with fast.enabled() if args.path == "fast" else fast.disabled():
        trace = Trace(fast) if args.trace and args.path == "fast" else None
        if args.stages:
            res = _stages(model, freqs, u, truth, library, args.check)
        else:
            res = close_loop(model, freqs, u, truth["alpha"], library=library, restarts=args.restarts,
                             per_type=args.per_type, max_effects=args.max_effects)
    if prof:
        prof.disable()
        prof.dump_stats(args.profile)
        pstats.Stats(args.profile).sort_stats("cumulative").print_stats(25)
        pstats.Stats(args.profile).sort_stats("tottime").print_stats(15)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if args.stages:
        print(f"stages: {wall:.1f} s wall, {cpu:.1f} s CPU")
        for k, v in res.items():
            print(f"  {k}: {v}")
        for c in counters:
            print(f"  {c}")
        print(f"  PARDISO: {pardiso.stats}")
        if args.json:
            with open(args.json, "a") as fh:
                fh.write(json.dumps({"path": args.path, "stages": res, "wall_s": wall, "cpu_s": cpu,
                                     "counts": {c.name: [c.calls, c.seconds] for c in counters},
                                     "pardiso": dict(pardiso.stats)}) + "\n")
        return 0
    if trace is not None:
        trace.report(args.trace)
    chosen = res.steps[0] if res.steps else None
    found = "-" if chosen is None else f"{chosen.effect} at {chosen.location} = {chosen.fit.values[0]:.4g}"
    print(f"closure: {wall:.1f} s wall, {cpu:.1f} s CPU; stages {', '.join(f'{k} {v:.1f} s' for k, v in res.seconds.items())}")
    for c in counters:
        print(f"  {c}")
    if args.path == "fast":
        print(f"  PARDISO: {pardiso.stats}")
    print(f"verdict {res.verdict}; found {found}; truth {truth['mass_kg']:.4g} kg at node {truth['node']}")
    print(f"rss before {res.baseline.rss:.6g}, after {res.final.rss:.6g}")
    if args.json:
        with open(args.json, "a") as fh:
            fh.write(json.dumps({"path": args.path, "restarts": args.restarts, "wall_s": wall, "cpu_s": cpu,
                                 "stages": res.seconds, "verdict": res.verdict, "found": found,
                                 "rss_before": res.baseline.rss, "rss_after": res.final.rss,
                                 "alpha_after": [float(a) for a in res.final.alpha],
                                 "counts": {c.name: [c.calls, c.seconds] for c in counters},
                                 "pardiso": dict(pardiso.stats) if args.path == "fast" else None,
                                 "library": [e.kind for e in library], "lines": int(freqs.size)}) + "\n")
    return 0


class Trace:
    """Full evaluations of the fast path by the closure's stage: every fit (``fit_update`` as the closure's modules
    call it) and every full response outside fits (the screens, the relocation screens), each with the chain of
    closure functions that asked for it, its full evaluations and what the fast fit logged."""

    SKIP = ("fast.py", "closure_speed.py")

    def __init__(self, fast):
        import importlib

        from fe_core.closure import screening

        self.fast, self.rows, self.depth, self.notes = fast, [], 0, []
        handler = logging.Handler(logging.DEBUG)
        handler.emit = lambda record: self.notes.append(record.getMessage())
        fast.log.addHandler(handler)
        fast.log.setLevel(logging.DEBUG)
        fast.log.propagate = False
        for name in fast._USERS:
            mod = importlib.import_module(name)
            mod.fit_update = self._wrap(mod.fit_update, "fit")
        screening.LinearisedResponse = self._wrap(screening.LinearisedResponse, "response")

    def _stage(self) -> str:
        import inspect

        names = [f.function for f in inspect.stack(0)[2:]
                 if "fe_core/closure/" in f.filename and not f.filename.endswith(self.SKIP)]
        return ">".join(n for n in reversed(names) if n != "close_loop")

    def _wrap(self, original, kind):
        def wrapped(*args, **kwargs):
            if self.depth:  # inside a traced fit: counted there
                return original(*args, **kwargs)
            stage, before, self.notes[:] = self._stage(), self.fast._BUILT[0], []
            self.depth += 1
            try:
                out = original(*args, **kwargs)
            finally:
                self.depth -= 1
            row = {"kind": kind, "stage": stage, "full": self.fast._BUILT[0] - before}
            if kind == "fit":
                effect = args[4] if len(args) > 4 else kwargs.get("effect")
                row.update(effect=None if effect is None else effect.kind,
                           location=args[5] if len(args) > 5 else kwargs.get("location"),
                           tol=kwargs.get("tol", 1e-8), rss=out.rss, message=out.message, notes=list(self.notes))
            self.rows.append(row)
            print(f"trace: {row['full']} full, {kind} {row.get('effect') or ''} {row.get('location') or ''} "
                  f"tol {row.get('tol', '')} {row['stage']}: {row.get('message', '')}", flush=True)
            return out

        return wrapped

    def report(self, path):
        with open(path, "w") as fh:
            for row in self.rows:
                fh.write(json.dumps(row) + "\n")
        by = {}
        for row in self.rows:
            n, fits_, full = by.get(row["stage"], (0, 0, 0))
            by[row["stage"]] = (n + 1, fits_ + (row["kind"] == "fit"), full + row["full"])
        print(f"full evaluations by stage (total {sum(r['full'] for r in self.rows)}; built {self.fast._BUILT[0]}):")
        for stage, (n, fits_, full) in by.items():
            print(f"  {full:4d} in {fits_:3d} fits, {n - fits_:3d} responses: {stage or '-'}")


def _stages(model, freqs, u, truth, library, full_check=False) -> dict:
    """The closure's pieces on the bracket, each timed (wall, CPU): the alpha-only fit from the true factors,
    the screen of every candidate, the point mass's fit (with alpha) at the true node from the screened value,
    and with ``full_check`` the point mass's check at its best-screened node with its moves."""
    from fe_core.closure import fits, screening

    out = {}

    def clock(name, fn):
        t, c = time.perf_counter(), time.process_time()
        value = fn()
        out[name] = {"wall_s": round(time.perf_counter() - t, 1), "cpu_s": round(time.process_time() - c, 1)}
        print(f"stage {name}: {out[name]}", flush=True)
        return value

    base = clock("alpha-only fit", lambda: fits.fit_update(model, freqs, u, truth["alpha"]))
    out["alpha-only fit"].update(rss=base.rss, full_evaluations=base.evaluations)
    screened = clock("screen", lambda: screening.screen(model, freqs, base, library))
    out["screen"].update(candidates=len(screened))
    mass = next(e for e in library if e.kind == "point_mass")
    first = next(c for c in screened if c.effect == "point_mass")
    print(f"screen: point mass first at {first.location} ({first.linear_values[0]:.4g} kg)", flush=True)
    where = f"node {truth['node']}"
    fit = clock("point-mass fit", lambda: fits.fit_update(model, freqs, u, base.alpha, mass, where,
                                                          [max(first.linear_values[0], 0.01)], tol=1e-6))
    out["point-mass fit"].update(location=where, mass_kg=float(fit.values[0]), rss=fit.rss,
                                 full_evaluations=fit.evaluations, true_mass_kg=truth["mass_kg"])
    if full_check:
        cand = clock("point-mass check", lambda: screening.check(model, freqs, u, base, mass, first))
        out["point-mass check"].update(screened=first.location, location=cand.location,
                                       mass_kg=float(cand.fit.values[0]), rss=cand.fit.rss,
                                       full_evaluations=cand.fit.evaluations, true_node=truth["node"])
    return out


if __name__ == "__main__":
    raise SystemExit(main())
