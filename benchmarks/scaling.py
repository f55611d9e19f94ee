"""Large models stage by stage: where the time and the memory of an update go (issue 41).

Three commands; every figure goes to ``runs/scaling/results.jsonl`` (one JSON line per measurement, with the
command, the code's commit, the load average before and after) and is printed as a table::

    python -m benchmarks.scaling make --size 0.003             # a refined bracket and its data (timing only)
    python -m benchmarks.scaling stages --model M.toml [--measured D.csv]
    python -m benchmarks.scaling update --model M.toml --measured D.csv [--code DIR] [--dask-workers N] [-- update flags]

``make`` meshes the L-bracket of ``data/examples/bracket`` at a finer element size (``make_mesh.py --size``)
into ``runs/scaling/`` with its model file, and writes FRF amplitudes of that same mesh at the bracket's true
factors with 1 % noise (15 lines at 0.95, 1, 1.05 times the first five natural frequencies). Data from the
model itself are for timing a converged update only; the large example with independent data is
``benchmarks/make/large.py``.

``stages`` measures, each in a fresh process (so the peak memory is the stage's own): reading and assembling
the model file; writing and mapping the model cache (:mod:`fe_core.io.cache`, when the code has it); the
factorisation of K (PARDISO, its fill ``nnz(L)``); one FE run (the FRF of the data's lines); one FE run with
its exact Jacobian; the six lowest modes (the band check of the preflight). Wall and CPU seconds and the peak
resident memory of the process.

``update`` runs ``python -m flows.update`` as a user does and samples its whole process tree (the flow, its
FE workers, Prefect's server) every ``--every`` seconds: the peak of the summed resident memory (RSS) and of
the summed proportional set size (PSS: a page shared by several processes, such as a memory-mapped model,
counted once in all), each process's peak, when the peak came and the log line then (the stage under way), the memory over the run
(``<run id>.memory.csv``), wall time and the FE runs of the summary. ``--code DIR`` runs
another checkout's code (``/work/main`` for the figures before a change).

The file has no imports from the project at module level, so ``python /path/to/benchmarks/scaling.py`` can
measure another checkout's code (``--code``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "runs" / "scaling"
RESULTS = OUT / "results.jsonl"
ALPHA_TRUE = [-0.10, 0.15, 0.10, -0.15, 0.20, -0.10]
WINDOW = (0.95, 1.0, 1.05)
N_MODES = 5
NOISE, SEED = 0.01, 3


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _commit(code: Path) -> str:
    try:
        return subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"


def _record(entry: dict) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with open(RESULTS, "a") as fh:
        fh.write(json.dumps(entry) + "\n")


# -- make -----------------------------------------------------------------------------------------------------
def make(size: float | None = None, model_file: Path | None = None) -> tuple[Path, Path]:
    """Mesh, model file and same-mesh data of the bracket at element size ``size`` (m); or the same-mesh data
    of another model file (``model_file``: its segments at alternating factors +-0.1, +-0.15, ...)."""
    import numpy as np

    OUT.mkdir(parents=True, exist_ok=True)
    if model_file is None:
        mesh = OUT / f"bracket_{size:g}.msh"
        if not mesh.exists():
            subprocess.run([sys.executable, str(REPO / "data/examples/bracket/make_mesh.py"), "--size", str(size),
                            "--out", str(mesh)], check=True)
        text = (REPO / "data/examples/bracket/model.toml").read_text()
        lines = [f'mesh = "{mesh.name}"' if line.startswith("mesh = ") else line for line in text.splitlines()]
        model_file = OUT / f"model_{size:g}.toml"
        model_file.write_text("\n".join(lines) + "\n")
        measured = OUT / f"measured_{size:g}.csv"
    else:
        measured = model_file.with_name(f"measured_{model_file.stem}.csv")
    if not measured.exists():
        from fe_core.io import read_model

        model = read_model(model_file)
        alpha = np.array(ALPHA_TRUE) if model.n_parameters == len(ALPHA_TRUE) else np.array(
            [(0.1 + 0.05 * (i % 3)) * (-1) ** i for i in range(model.n_parameters)])
        natural = model.natural_frequencies(alpha, n_modes=N_MODES + 1)
        freqs = np.round(np.concatenate([f * np.asarray(WINDOW) for f in natural[:N_MODES]]), 1)
        Z = np.abs(model.frf(alpha, freqs))
        amp = Z * (1 + NOISE * np.random.default_rng(SEED).standard_normal(Z.shape))
        with open(measured, "w") as fh:
            fh.write("sensor,frequency_hz,amplitude\n")
            for i, f in enumerate(freqs):
                for j in range(Z.shape[1]):
                    fh.write(f"{j + 1},{float(f)!r},{float(amp[i, j])!r}\n")
        print(f"{model_file}: {model.n_dofs} free DOFs; {measured}: {freqs.size} lines x {Z.shape[1]} sensors")
    return model_file, measured


# -- stages ---------------------------------------------------------------------------------------------------
_STAGE_CODE = r'''
import json, os, resource, sys, time
import numpy as np
stage, model_file, freqs, cache_dir = sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), sys.argv[4]
alpha_given = np.array(%(alpha)r)
def factors(n):
    # the given factors, zero for segments beyond them (a model without its truth.json)
    out = np.zeros(n)
    out[:min(n, alpha_given.size)] = alpha_given[:n]
    return out
out = {}
t0, c0 = time.perf_counter(), time.process_time()
def done(**extra):
    out.update(stage=stage, seconds=round(time.perf_counter() - t0, 2), cpu=round(time.process_time() - c0, 2),
               peak_gb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 3), **extra)
    print("RESULT " + json.dumps(out), flush=True)
def checksum():
    # the model file and its mesh: the large example's model.toml is the same text at every size
    import hashlib
    from fe_core.io import model_files
    digest = hashlib.sha256()
    for f in model_files(model_file):
        digest.update(f.name.encode() + b"\0" + open(f, "rb").read())
    return digest.hexdigest()
def model():
    if cache_dir != "-":
        from fe_core.io import cache
        folder = cache.lookup(cache_dir, checksum())
        if folder is not None:
            return cache.load(folder)
    from fe_core.io import read_model
    return read_model(model_file)
if stage == "read":
    from fe_core.io import read_model
    m = read_model(model_file)
    seg = m.stiffness_segments
    done(dofs=int(m.n_dofs), nnz=int(seg.pattern.nnz),
         matrices_gb=round((getattr(seg, "nbytes", 0) + getattr(m.mass_segments, "nbytes", 0)) / 1e9, 3))
elif stage == "cache":
    from fe_core.io import read_model, cache
    m = read_model(model_file)
    key = checksum()
    t0, c0 = time.perf_counter(), time.process_time()
    folder = cache.save(m, cache_dir, key)
    done(write=True, folder=str(folder))
elif stage == "mapped":
    m = model()
    done(dofs=int(m.n_dofs))
else:
    m = model()
    t0, c0 = time.perf_counter(), time.process_time()
    if stage == "factor":
        from fe_core.solvers.frf import spd_solver
        K = m.stiffness(factors(m.n_segments))
        t0, c0 = time.perf_counter(), time.process_time()
        solve = spd_solver(K)
        factor_s = time.perf_counter() - t0
        extra = {}
        try:
            from fe_core.solvers import pardiso
            h = [h for pool in pardiso._POOL.values() for h in pool][0]
            extra = {"nnz_L": int(h.solver.get_iparm(18)), "factor_mb": int(h.solver.get_iparm(17)) // 1000,
                     "factor_mflop": int(getattr(h, "factor_mflop", 0))}
        except Exception:
            pass
        b = np.random.default_rng(0).standard_normal((K.shape[0], 8))
        t = time.perf_counter(); solve(b[:, :1]); one = time.perf_counter() - t
        t = time.perf_counter(); solve(b); eight = time.perf_counter() - t
        done(factor_s=round(factor_s, 2), solve_1rhs_s=round(one, 3), solve_8rhs_s=round(eight, 3), **extra)
    elif stage == "frf":
        m.parameter_frf(factors(m.n_parameters), freqs)
        done()
    elif stage == "jacobian":
        from fe_core.solvers.sensitivity import frf_jacobian
        Z, dZ, info = frf_jacobian(m, factors(m.n_parameters), freqs, return_info=True)
        done(dimension=int(info.dimension), solves=int(info.solves))
    elif stage == "modes":
        f = m.natural_frequencies(np.zeros(m.n_segments), 6)
        done(modes_hz=[round(float(x), 1) for x in f])
'''


def _frequencies(measured: Path | None) -> list[float]:
    """The measured file's lines, Hz (a table with a ``frequency_hz`` column; ``#`` lines are comments)."""
    if measured is None:
        return [300.0, 570.0, 1300.0, 2400.0, 3200.0]
    rows = [r for r in Path(measured).read_text().splitlines() if r.strip() and not r.startswith("#")]
    column = rows[0].split(",").index("frequency_hz")
    return sorted({float(r.split(",")[column]) for r in rows[1:]})


def _alpha(model_file: Path) -> list[float]:
    """The factors the stages run at: ``truth.json``'s beside the model file (the large example), else the
    bracket's true factors."""
    truth = Path(model_file).with_name("truth.json")
    if truth.exists():
        alpha = json.loads(truth.read_text()).get("alpha")
        if isinstance(alpha, dict):
            return [float(v) for v in alpha.values()]
        if alpha is not None:
            return [float(v) for v in alpha]
    return list(ALPHA_TRUE)


def stages(model_file: Path, measured: Path | None, code: Path, which: list[str], threads: int) -> list[dict]:
    """Each stage in a fresh process of ``code``'s checkout; returns the records."""
    freqs = _frequencies(measured)
    cache_dir = OUT / "stage-cache"
    has_cache = (code / "fe_core" / "io" / "cache.py").exists()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": str(threads), "OPENBLAS_NUM_THREADS": "1"}
    out = []
    for stage in which:
        if stage in ("cache", "mapped") and not has_cache:
            continue
        use_cache = has_cache and stage not in ("read", "cache")
        if stage == "cache":
            shutil.rmtree(cache_dir, ignore_errors=True)
        load0 = _load()
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _STAGE_CODE % {"alpha": _alpha(model_file)}, stage, str(model_file),
                               json.dumps(freqs), str(cache_dir) if (use_cache or stage == "cache") else "-"],
                              cwd=code, env=env, capture_output=True, text=True)
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        if proc.returncode or not lines:
            print(proc.stdout[-2000:], proc.stderr[-4000:], file=sys.stderr)
            raise SystemExit(f"stage {stage} failed")
        entry = json.loads(lines[-1][7:])
        entry.update(kind="stage", model=str(model_file), code=str(code), commit=_commit(code), threads=threads,
                     load_before=load0, load_after=_load(), process_seconds=round(time.perf_counter() - t0, 2),
                     lines=len(freqs), from_cache=use_cache)
        _record(entry)
        print(json.dumps(entry), flush=True)
        out.append(entry)
    return out


# -- update ---------------------------------------------------------------------------------------------------
class TreeSampler:
    """Samples a process and its descendants: summed RSS and PSS, each process's peak RSS."""

    def __init__(self, pid: int, every: float):
        import psutil

        self.root = psutil.Process(pid)
        self.every = every
        self.peak_rss = self.peak_pss = 0.0
        self.peak_time = None  # time.time() of the tree's RSS peak
        self.series: list[tuple[float, float, float]] = []  # (time.time(), tree RSS GB, tree PSS GB)
        self.per_process: dict[int, dict] = {}
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        import psutil

        while not self._stop.is_set():
            try:
                procs = [self.root, *self.root.children(recursive=True)]
            except psutil.Error:
                break
            rss = pss = 0.0
            for p in procs:
                try:
                    info = p.memory_full_info()
                    name = " ".join(p.cmdline()[:4])[:90]
                except psutil.Error:
                    continue
                rss += info.rss
                pss += info.pss
                rec = self.per_process.setdefault(p.pid, {"name": name, "peak_rss_gb": 0.0, "peak_pss_gb": 0.0})
                rec["peak_rss_gb"] = max(rec["peak_rss_gb"], info.rss / 1e9)
                rec["peak_pss_gb"] = max(rec["peak_pss_gb"], info.pss / 1e9)
            now = time.time()
            self.series.append((now, rss / 1e9, pss / 1e9))
            if rss / 1e9 > self.peak_rss:
                self.peak_rss, self.peak_time = rss / 1e9, now
            self.peak_pss = max(self.peak_pss, pss / 1e9)
            self._stop.wait(self.every)

    def start(self):
        self.thread.start()

    def stop(self):
        self._stop.set()
        self.thread.join()


def line_at(log_text: str, when: float) -> str | None:
    """The log's last line stamped at or before ``when`` (``time.time()``; the log's ``HH:MM:SS.mmm |`` stamps are
    the machine's local time of the same day): the stage under way at the memory's peak."""
    stamp = time.strftime("%H:%M:%S", time.localtime(when)) + f".{int(when % 1 * 1000):03d}"
    found = None
    for line in log_text.splitlines():
        head = line[:12]
        if len(head) == 12 and head[2] == head[5] == ":" and head[8] == "." and line[12:15] == " | ":
            if head > stamp:
                break
            found = line
    return found


def _write_series(path: Path, series) -> None:
    """The sampled tree's memory over the run, one row per sample: seconds from the first, RSS and PSS (GB)."""
    t0 = series[0][0] if series else 0.0
    path.write_text("t_s,tree_rss_gb,tree_pss_gb\n" + "".join(f"{t - t0:.1f},{r:.3f},{p:.3f}\n" for t, r, p in series))


@contextlib.contextmanager
def _dask_cluster(workers: int, code: Path):
    """A Dask LocalCluster of ``workers`` processes (one thread each, one BLAS thread, ``code``'s checkout on
    their path), its workers children of this process; yields its scheduler address (None: no cluster)."""
    if not workers:
        yield None
        return
    for key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[key] = "1"
    os.environ["PYTHONPATH"] = str(code)
    from distributed import LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def update(model_file: Path, measured: Path, code: Path, run_id: str, extra: list[str], every: float,
           dask_workers: int = 0) -> dict:
    """``python -m flows.update`` of ``code`` on the model and data, sampled; returns the record. With
    ``dask_workers``, its FE runs go to a LocalCluster of that many workers started here, and the sampled tree
    is this process's (the cluster's scheduler runs in it, its workers are its children, and so is the flow)."""
    runs = OUT / "runs"
    cmd = [sys.executable, "-m", "flows.update", "--model", str(model_file), "--measured", str(measured),
           "--run-id", run_id, "--runs-dir", str(runs), *extra]
    shutil.rmtree(runs / run_id, ignore_errors=True)
    OUT.mkdir(parents=True, exist_ok=True)  # a fresh checkout has no runs/ yet
    load0 = _load()
    log = OUT / f"{run_id}.log"
    with _dask_cluster(dask_workers, code) as address, open(log, "w") as fh:
        if address is not None:
            cmd += ["--fe-backend", "dask", "--dask-address", address]
        t0, t0_epoch = time.perf_counter(), time.time()
        proc = subprocess.Popen(cmd, cwd=code, stdout=fh, stderr=subprocess.STDOUT)
        sampler = TreeSampler(os.getpid() if address is not None else proc.pid, every)
        sampler.start()
        rc = proc.wait()
        sampler.stop()
        wall = time.perf_counter() - t0
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    _write_series(OUT / f"{run_id}.memory.csv", sampler.series)
    peak_line = line_at(log.read_text(errors="replace"), sampler.peak_time) if sampler.peak_time else None
    summary = {}
    path = runs / run_id / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
    entry = {"kind": "update", "model": str(model_file), "measured": str(measured), "code": str(code),
             "commit": _commit(code), "command": " ".join(cmd), "returncode": rc, "wall_s": round(wall, 1),
             "cpu_s_children": round(children.ru_utime + children.ru_stime, 1),
             "peak_tree_rss_gb": round(sampler.peak_rss, 2), "peak_tree_pss_gb": round(sampler.peak_pss, 2),
             "peak_after_s": round(sampler.peak_time - t0_epoch, 1) if sampler.peak_time else None,
             "peak_during": peak_line[:300] if peak_line else None, "memory_series": str(OUT / f"{run_id}.memory.csv"),
             "processes": sorted(({"pid": k, **{a: (round(b, 2) if isinstance(b, float) else b) for a, b in v.items()}}
                                  for k, v in sampler.per_process.items()), key=lambda r: -r["peak_rss_gb"])[:6],
             "load_before": load0, "load_after": _load(), "log": str(log), "dask_workers": dask_workers,
             "summary": {k: summary.get(k) for k in ("converged", "parameters", "fe_evaluations", "fe_runs",
                                                     "cost", "status") if k in summary}}
    _record(entry)
    print(json.dumps(entry, indent=1), flush=True)
    return entry


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("make", help="a refined bracket and its same-mesh data")
    p.add_argument("--size", type=float, help="element size, m (0.0039: 118k DOFs, 0.003: 214k, "
                                              "0.0022: 464k, 0.0017: 950k)")
    p.add_argument("--model", type=Path, help="instead: same-mesh data of this model file")
    p = sub.add_parser("stages", help="stage by stage, each in a fresh process")
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--measured", type=Path)
    p.add_argument("--code", type=Path, default=REPO)
    p.add_argument("--threads", type=int, default=1, help="MKL threads of the stages' processes")
    p.add_argument("--stages", nargs="+", default=["read", "cache", "mapped", "factor", "frf", "jacobian", "modes"])
    p = sub.add_parser("update", help="the default update, its process tree sampled")
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--measured", type=Path, required=True)
    p.add_argument("--code", type=Path, default=REPO)
    p.add_argument("--run-id", default=None)
    p.add_argument("--every", type=float, default=1.0, help="sampling interval, s")
    p.add_argument("--dask-workers", type=int, default=0,
                   help="FE runs on a Dask LocalCluster of this many workers started here (one thread each)")
    p.add_argument("extra", nargs="*", help="further flows.update flags (after --)")
    args = parser.parse_args(argv)
    if args.command == "make":
        make(args.size, args.model)
    elif args.command == "stages":
        stages(args.model.resolve(), args.measured, args.code.resolve(), args.stages, args.threads)
    else:
        run_id = args.run_id or f"{args.model.stem}-{_commit(args.code.resolve())}"
        update(args.model.resolve(), args.measured.resolve(), args.code.resolve(), run_id, args.extra, args.every,
               args.dask_workers)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
