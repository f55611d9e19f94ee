"""Route B (ccx as a black box) through the flows, on shell thicknesses: FE runs, rounds and wall time to the floor.

    nice -n 10 python -m benchmarks.calculix_route_b [--out table.md]

The example's cylindrical panel (benchmarks/make/shell_panel.py) on a 6 x 6 S8R mesh, four thickness factors
(``[[parameters]] kind = "shell_thickness"``), truth [0.03, -0.04, 0.05, -0.03]; the measured FRF is ccx's own
on the same mesh at the truth with 1 % noise (seed 3; a speed benchmark: the floor is the noise, which the
check is told, ``--noise 0.01``), 30 frequencies (10 across 0.85-1.15 of each of the first three modes), 7
sensors. Each FE run is one ccx process (one thread, 20 modes, one steady-state step per frequency) in its own
folder under the run folder.

* hybrid (``--strategy hybrid``): its local phase takes forward-difference Jacobians, m + 1 = 5 ccx runs in
  one round; the paper's loop (``--strategy adaptive --emulate errors``, its polish included); both through
  ``python -m flows.update``'s flow with ``--n-jobs 1``, ``--n-jobs 2`` (joblib/loky processes) and a 2-worker
  Dask ``LocalCluster`` (``--fe-backend dask``, one thread per worker);
* DFO-LS (``dfols.solve``, its default interpolation model, rhobeg 0.05, sequential runs) on the same residual
  (log amplitudes) and box through the same model object, outside the flows (no DFO-LS strategy in them).

FE-stage seconds: the wall time of the stages that run FE runs (local/global, fe/polish), each from the
previous stage's end to its own (so including the strategy's own work in that stage). The run's own wall time
includes the intervals (forward differences too) and the summary.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.make import shell_panel

TRUTH = np.array([0.03, -0.04, 0.05, -0.03])
MESH = (6, 6)
N_MODES = 20


def make_example(folder: Path) -> tuple[Path, Path]:
    """(model.toml, measured.csv) of the benchmark in ``folder``."""
    from fe_core.io import read_model

    cards, ids = shell_panel.panel(*MESH)
    (folder / "panel.inp").write_text(cards)
    params = "".join(f'\n[[parameters]]\nname = "t_{s.lower()}"\nkind = "shell_thickness"\nelset = "{s}"\n'
                     "bounds = [-0.3, 0.3]\n" for s in shell_panel.SEGMENTS)
    sensors = "".join(f'\n[[sensors]]\nnode = {ids[shell_panel.point(u, v)]}\ndirection = "{d}"\n'
                      for u, v, d in shell_panel.SENSORS)
    a, b = shell_panel.DAMPING
    toml = (f'units = "SI"\nsolver = "calculix"\ndeck = "panel.inp"\nsolver_timeout = 120.0\nn_modes = {N_MODES}\n'
            f"\n[damping]\na = {a}\nb = {b}\n{params}{sensors}\n[[excitations]]\nnset = \"TIP_CORNER\"\n"
            'direction = "z"\n')
    (folder / "model.toml").write_text(toml)
    model = read_model(folder / "model.toml").with_workdir(folder / "truth")
    f0 = model.natural_frequencies(np.zeros(4), 3)
    freqs = np.concatenate([f * np.linspace(0.85, 1.15, 10) for f in f0])
    Z = model.parameter_frf(TRUTH, freqs)
    u = np.abs(Z) * (1 + 0.01 * np.random.default_rng(3).standard_normal(Z.shape))
    rows = ["sensor,frequency_hz,amplitude"] + [f"{j + 1},{float(f)!r},{float(u[k, j])!r}"
                                                for k, f in enumerate(freqs) for j in range(u.shape[1])]
    (folder / "measured.csv").write_text("\n".join(rows) + "\n")
    return folder / "model.toml", folder / "measured.csv"


def fe_stage_seconds(root: Path) -> float:
    """Wall seconds of the run's FE stages (each from the previous stage's end to its own)."""
    stages = []
    for rec in root.glob("iteration=*/stage=*/_stage.json"):
        stages.append((json.loads(rec.read_text())["finished_unix"], (rec.parent / "runs.parquet").exists()))
    stages.sort()
    start = (root / "manifest.json").stat().st_mtime
    total, before = 0.0, start
    for end, fe in stages:
        if fe:
            total += end - before
        before = end
    return total


def flow_row(model: Path, measured: Path, runs: Path, strategy: str, backend: str, jobs: int,
             address: str | None) -> dict:
    from flows import update
    from flows.config import UpdateConfig

    extra = {"emulate": "errors"} if strategy == "adaptive" else {}
    run_id = f"{strategy}-{backend}-{jobs}"
    config = UpdateConfig(model=str(model), measured=str(measured), run_id=run_id, runs_dir=str(runs),
                          strategy=strategy, n_jobs=jobs, fe_backend=backend, dask_address=address, noise=0.01,
                          **extra)
    t0 = time.perf_counter()
    s = update.update_flow(config)
    wall = time.perf_counter() - t0
    x = np.array([s["parameters"][f"alpha_{i + 1}"] for i in range(4)])
    where = {"loky": f"{jobs} joblib process{'es' if jobs > 1 else ''}", "dask": f"Dask LocalCluster, {jobs} workers"}
    return {"method": f"{'hybrid (FD)' if strategy == 'hybrid' else 'paper loop'}, {where[backend]}",
            "fe_runs": int(round(s["fe_equivalents"])), "rounds": int(s["rounds"]), "wall": wall,
            "fe_wall": fe_stage_seconds(runs / run_id), "error": float(np.max(np.abs(x - TRUTH))),
            "converged": bool(s["converged"])}


def dfols_row(model_path: Path, measured: Path, folder: Path) -> dict:
    import dfols

    from fe_core.io import read_model
    from tasks.io.measured import read_measured

    model = read_model(model_path).with_workdir(folder)
    data = read_measured(measured)
    freqs, u = np.asarray(data.frequencies_hz, float), np.asarray(data.amplitude, float)
    count = [0]

    def residual(theta):
        count[0] += 1
        return np.log(np.abs(model.parameter_frf(theta, freqs))).ravel() - np.log(u).ravel()

    t0 = time.perf_counter()
    sol = dfols.solve(residual, np.zeros(4), bounds=(-0.3 * np.ones(4), 0.3 * np.ones(4)), rhobeg=0.05,
                      rhoend=1e-5, maxfun=200)
    wall = time.perf_counter() - t0
    at_truth = residual(TRUTH)
    count[0] -= 1
    # its own stop ("rho has reached rhoend") is no floor test: compare its sum of squares with the truth's
    return {"method": f"DFO-LS, sequential (outside the flows; sum r^2 {sol.obj:.3g}, at the truth "
                      f"{at_truth @ at_truth:.3g})", "fe_runs": count[0], "rounds": count[0], "wall": wall,
            "fe_wall": wall, "error": float(np.max(np.abs(sol.x - TRUTH))),
            "converged": bool(sol.obj <= 1.1 * (at_truth @ at_truth))}


def main(out: Path | None = None) -> None:
    from distributed import LocalCluster
    from prefect.testing.utilities import prefect_test_harness

    rows = []
    with tempfile.TemporaryDirectory() as tmp, prefect_test_harness(server_startup_timeout=120):
        tmp = Path(tmp)
        model, measured = make_example(tmp)
        runs = tmp / "runs"
        for strategy in ("hybrid", "adaptive"):
            rows.append(flow_row(model, measured, runs, strategy, "loky", 1, None))
            rows.append(flow_row(model, measured, runs, strategy, "loky", 2, None))
            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                rows.append(flow_row(model, measured, runs, strategy, "dask", 2, cluster.scheduler_address))
        rows.append(dfols_row(model, measured, tmp / "dfols"))
    lines = ["| method | FE runs | rounds | wall s | FE-stage s | max factor error | at the floor |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['method']} | {r['fe_runs']} | {r['rounds']} | {r['wall']:.1f} | {r['fe_wall']:.1f} | "
              f"{r['error']:.4f} | {'yes' if r['converged'] else 'no'} |" for r in rows]
    for k in (0, 3):
        one, two, dask = rows[k:k + 3]
        lines.append(f"\n{one['method'].split(',')[0]}: FE-stage speed-up {one['fe_wall'] / two['fe_wall']:.2f} with 2 "
                     f"joblib processes, {one['fe_wall'] / dask['fe_wall']:.2f} with 2 Dask workers")
    text = "\n".join(lines)
    print(text)
    if out is not None:
        out.write_text(text + "\n")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="also write the table to this file")
    main(parser.parse_args().out)
