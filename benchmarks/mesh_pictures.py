"""The docs' mesh pictures (docs/guide/model-files.md), and how long drawing and model.vtu take on the 35k-DOF tet10 bracket.

``nice -n 5 python -m benchmarks.mesh_pictures`` (one run; about a minute on 2 busy cores plus the
benchmark update when its run is missing):

1. the benchmark's run ``--run-id`` (made with ``python -m flows.update --run-id <id>`` when missing):
   ``docs/figures/mesh-segments.png`` (segments, sensors, excitation) and ``docs/figures/mesh-factors.png``
   (its updated alpha per segment), drawn by the report's own functions;
2. the L-bracket (``data/examples/bracket/bracket.msh``, tet10, 33,681 free DOFs) with its
   ``model.toml`` when there is one, else one written here (six segments, bolted at the holes,
   three sensors and a hammer on the web): ``docs/figures/mesh-bracket.png`` and the times of each step,
   written to ``docs/results/mesh-pictures.md``.

``python -m benchmarks.mesh_pictures --bracket-run <id>`` instead draws the updated factors of a finished
update run of the bracket example (``python -m flows.update --model data/examples/bracket/model.toml ...``,
minutes, so not started here) on its mesh, ``docs/figures/mesh-bracket-factors.png``, and that model's segments,
sensors and hammer, ``docs/figures/mesh-bracket.png``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FIGURES = REPO / "docs" / "figures"
BRACKET = REPO / "data" / "examples" / "bracket"

#: The bracket as a model file, when data/examples/bracket/model.toml is not there (yet).
BRACKET_TOML = """units = "SI"
mesh = "{mesh}"
[damping]
a = 0.01
b = 1e-5
[[materials]]
E = 2.06e11
nu = 0.3
rho = 7850.0
{segments}
[[supports]]
nodes = "bolt_holes"
fix = ["x", "y", "z"]
[[sensors]]
name = "web_top_x"
point = [0.0, 0.0, 0.12]
direction = "x"
[[sensors]]
name = "web_top_y"
point = [0.01, 0.08, 0.12]
direction = "y"
[[sensors]]
name = "rib_xz"
point = [0.035, 0.004, 0.035]
direction = [1.0, 0.0, 1.0]
[[excitations]]
name = "hammer"
point = [0.0, 0.04, 0.12]
direction = "x"
"""
SEGMENTS = ("foot_inner", "foot_outer", "web_lower", "web_upper", "rib_left", "rib_right")


def _timed(fn, *args, repeat: int = 1, **kwargs):
    """(result, (wall, CPU) seconds): medians of ``repeat`` calls. On a machine shared with other
    jobs the CPU time of this process is the steadier figure."""
    walls, cpus = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn(*args, **kwargs)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return out, (float(np.median(walls)), float(np.median(cpus)))


def benchmark_pictures(run_id: str, runs_dir: Path) -> dict:
    """docs/figures/mesh-segments.png and docs/figures/mesh-factors.png from the benchmark run ``run_id``."""
    from tasks.report.mesh import MeshView, plot_mesh_factors, plot_mesh_segments, read_run_model

    root = runs_dir / run_id
    if not (root / "summary.json").exists():
        print(f"{root}: no finished run; running python -m flows.update --run-id {run_id}", flush=True)
        subprocess.run([sys.executable, "-m", "flows.update", "--run-id", run_id, "--runs-dir", str(runs_dir)],
                       cwd=REPO, check=True)
    summary = json.loads((root / "summary.json").read_text())
    model = read_run_model(json.loads((root / "manifest.json").read_text())["config"]["model"])
    alpha = np.array([summary["parameters"][n] for n in model.parameter_names])
    view = MeshView(model)
    plot_mesh_segments(model, FIGURES / "mesh-segments.png", view,
                       "The benchmark (data/benchmark/model.toml): segments, sensors and excitation")
    plot_mesh_factors(model, alpha, FIGURES / "mesh-factors.png", view=view)
    return {"run": run_id, "alpha": alpha.round(4).tolist(), "overall_error": summary["overall_error"]}


def bracket_run_factors(run_id: str, runs_dir: Path) -> dict:
    """docs/figures/mesh-bracket-factors.png: the updated factors of the bracket run ``run_id``, and docs/figures/mesh-bracket.png:
    its model's segments, sensors and hammer, by the report's functions."""
    from tasks.model_vtu import factors_from_parameters
    from tasks.report.mesh import MeshView, plot_mesh_factors, plot_mesh_segments, read_run_model

    root = runs_dir / run_id
    if not (root / "summary.json").exists():
        raise SystemExit(f"{root}: no finished run; update the bracket first, e.g. python -m flows.update --model "
                         f"data/examples/bracket/model.toml --measured data/examples/bracket/measured.csv "
                         f"--run-id {run_id} (see data/examples/bracket/README.md)")
    summary = json.loads((root / "summary.json").read_text())
    model = read_run_model(json.loads((root / "manifest.json").read_text())["config"]["model"])
    alpha, gamma = factors_from_parameters(summary["parameters"], model)
    truth = json.loads((BRACKET / "truth.json").read_text())["alpha"]
    title = (f"The L-bracket's updated stiffness factors (run {run_id}, overall error {summary['overall_error']:.2%}); "
             f"truth {', '.join(f'{t:+.2f}' for t in truth)}")
    view = MeshView(model)
    plot_mesh_segments(model, FIGURES / "mesh-bracket.png", view,
                       "The L-bracket (tet10): segments, sensors and excitation")
    plot_mesh_factors(model, alpha, FIGURES / "mesh-bracket-factors.png", gamma, view, title=title)
    return {"run": run_id, "alpha": alpha.round(4).tolist(), "truth": truth, "overall_error": summary["overall_error"]}


def bracket_timings(model_file: Path | None) -> dict:
    """Read the bracket, draw both pictures, build model.vtu (6 modes); the time of each step."""
    from fe_core.io import read_model
    from fe_core.io.vtu import model_vtu
    from tasks.report.mesh import MeshView, plot_mesh_factors, plot_mesh_segments

    with tempfile.TemporaryDirectory() as tmp:
        if model_file is None:
            model_file = Path(tmp) / "model.toml"
            segments = "\n".join(f'[[segments]]\nset = "{s}"' for s in SEGMENTS)
            model_file.write_text(BRACKET_TOML.format(mesh=BRACKET / "bracket.msh", segments=segments))
        model, t_read = _timed(read_model, model_file)
        view, t_view = _timed(MeshView, model, repeat=3)
        _, t_seg = _timed(plot_mesh_segments, model, FIGURES / "mesh-bracket.png", view,
                          "The L-bracket (tet10): segments, sensors and excitation", repeat=3)
        # The factors picture's cost does not depend on the values; these are not an update's result.
        alpha = np.linspace(-0.3, 0.3, model.n_segments)
        _, t_fac = _timed(plot_mesh_factors, model, alpha, Path(tmp) / "factors.png", None, view, repeat=3)
        _, t_fac_gamma = _timed(plot_mesh_factors, model, alpha, Path(tmp) / "factors-gamma.png", -alpha, view,
                                repeat=3)
        grid, t_vtu = _timed(model_vtu, model, alpha)
        path = Path(tmp) / "model.vtu"
        import meshio

        _, t_write = _timed(meshio.write, path, grid)
        size_mb = path.stat().st_size / 1e6
    return {"model_file": str(model_file), "cells": model.mesh.n_cells, "free_dofs": model.n_dofs,
            "boundary_faces": view.n_boundary, "drawn_faces": int(view.cell.size),
            "read_s": t_read, "surface_s": t_view, "segments_png_s": t_seg, "factors_png_s": t_fac,
            "factors_gamma_png_s": t_fac_gamma, "modes_s": t_vtu, "vtu_write_s": t_write, "vtu_mb": size_mb,
            "frequencies_hz": [float(n.split(" at ")[1].split()[0]) for n in grid.point_data]}


def _row(what: str, times: tuple[float, float]) -> str:
    return f"| {what} | {times[0]:.2f} s | {times[1]:.2f} s |"


def write_table(bench: dict, bracket: dict) -> Path:
    load = os.getloadavg()
    lines = [
        "# Mesh pictures and model.vtu: times on the tet10 bracket",
        "",
        "Written by `nice -n 5 python -m benchmarks.mesh_pictures` (one run, one BLAS thread, "
        f"{platform.machine()}, load average {load[0]:.1f} on {os.cpu_count()} cores, shared with other jobs).",
        "",
        f"The bracket: {bracket['cells']:,} tet10 cells, {bracket['free_dofs']:,} free DOFs; its outer surface has "
        f"{bracket['boundary_faces']:,} faces (corner triangles), of which {bracket['drawn_faces']:,} face the "
        "viewer and are drawn.",
        "",
        "| step | wall | CPU of this process |",
        "|---|---|---|",
        _row("read and assemble the model (not part of the pictures)", bracket["read_s"]),
        _row("outer surface and back-face culling (`MeshView`), median of 3", bracket["surface_s"]),
        _row("segments, sensors and excitation picture (PNG), median of 3", bracket["segments_png_s"]),
        _row("updated-factors picture, alpha only, median of 3", bracket["factors_png_s"]),
        _row("updated-factors picture, alpha and gamma, median of 3", bracket["factors_gamma_png_s"]),
        _row("model.vtu: 6 modes of the updated model (shift-invert Lanczos, PARDISO Cholesky of K)",
             bracket["modes_s"]),
        _row(f"model.vtu: meshio write ({bracket['vtu_mb']:.1f} MB)", bracket["vtu_write_s"]),
        "",
        "Modes at alpha = " + ", ".join(f"{a:.2f}" for a in np.linspace(-0.3, 0.3, 6)) + ": "
        + ", ".join(f"{f:.0f}" for f in bracket["frequencies_hz"]) + " Hz.",
        "",
        f"Benchmark pictures (`docs/figures/mesh-segments.png`, `docs/figures/mesh-factors.png`) from run `{bench['run']}`: "
        f"overall error {bench['overall_error']:.3%}, alpha = {bench['alpha']}.",
        "",
    ]
    path = REPO / "docs" / "results" / "mesh-pictures.md"
    path.write_text("\n".join(lines))
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.mesh_pictures", description=__doc__.splitlines()[0])
    p.add_argument("--run-id", default="mesh-pictures", help="the benchmark run to draw (made when missing)")
    p.add_argument("--runs-dir", default=str(REPO / "runs"))
    p.add_argument("--bracket-model", type=Path, default=None,
                   help="the bracket's model.toml (default data/examples/bracket/model.toml when it exists)")
    p.add_argument("--bracket-run", metavar="ID",
                   help="only draw docs/figures/mesh-bracket-factors.png from this finished update run of the bracket")
    args = p.parse_args(argv)
    if args.bracket_run:
        print(json.dumps(bracket_run_factors(args.bracket_run, Path(args.runs_dir)), indent=1))
        return 0
    bracket_file = args.bracket_model or (BRACKET / "model.toml" if (BRACKET / "model.toml").exists() else None)
    bench = benchmark_pictures(args.run_id, Path(args.runs_dir))
    bracket = bracket_timings(bracket_file)
    print(json.dumps({"benchmark": bench, "bracket": bracket}, indent=1))
    print(f"written {write_table(bench, bracket)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
