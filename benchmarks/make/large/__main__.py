"""Generate the large example at about N free DOFs: ``python -m benchmarks.make.large --dofs N``.

See the package's docstring (``benchmarks/make/large/__init__.py``) for what is written and how.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import resource
import shutil
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from . import (ALPHA_RANGE, CUTOFF_FACTOR, F_START, F_STEP, MASS_AT, N_LINES, NOISE, NOISE_SEED, OUT, TEMPLATE,
               TRUTH_SEED)

log = logging.getLogger("benchmarks.make.large")


def frequencies() -> np.ndarray:
    """The measured lines, Hz, shape (N_LINES,)."""
    return F_START + F_STEP * np.arange(N_LINES)


def true_factors(n: int) -> np.ndarray:
    """The true alpha of the n segments: uniform in ALPHA_RANGE (seed TRUTH_SEED), rounded to 0.001."""
    return np.round(np.random.default_rng(TRUTH_SEED).uniform(*ALPHA_RANGE, size=n), 3)


def add_noise(H: np.ndarray, seed: int = NOISE_SEED, level: float = NOISE) -> np.ndarray:
    """``H (1 + level (n1 + i n2) / sqrt(2))``, n1, n2 standard normal from ``seed``; same shape as H."""
    n = np.random.default_rng(seed).standard_normal((2,) + H.shape)
    return H * (1 + level * (n[0] + 1j * n[1]) / np.sqrt(2))


def write_measured(path: Path, freqs: np.ndarray, Z: np.ndarray, sensors: list, reference: str, note: str):
    """A long CSV table (docs/measured-formats.md): response, reference, frequency_hz, real, imag (m/N)."""
    lines = [f"# {note}", "# kind = receptance", "response,reference,frequency_hz,real,imag"]
    for j, name in enumerate(sensors):
        lines += [f"{name},{reference},{f!r},{z.real:.12e},{z.imag:.12e}" for f, z in zip(freqs.tolist(), Z[:, j])]
    path.write_text("\n".join(lines) + "\n")


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def peak_gb() -> float:
    """This process's peak resident memory so far, GB (Linux: ru_maxrss in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def generate(dofs: float, out: Path, size: float | None = None, per_circle: int | None = None,
             cutoff_factor: float = CUTOFF_FACTOR, point_mass: float | None = None,
             mass_at=MASS_AT):
    """Mesh the panel, assemble it with scikit-fem at the truth, synthesise and write its measurement.

    Parameters
    ----------
    dofs : float
        About this many free DOFs (sets the mesh size, :func:`.geometry.size_for_dofs`).
    out : Path
        The folder written: panel.msh, model.toml, measured.csv, truth.json, generation.json.
    size : float, optional
        The mesh size (m) instead of the one for ``dofs``.
    per_circle : int, optional
        Elements per circle on the holes (default :data:`.geometry.PER_CIRCLE`).
    cutoff_factor : float
        Modes are kept up to this many times the band's top.
    point_mass : float, optional
        Add to the measured structure a point mass of this share of the panel's mass, which the model file
        does not declare (the closure's case), at the node nearest ``mass_at`` (m).

    Returns
    -------
    dict
        ``generation`` (``generation.json``'s content), ``panel`` (:class:`.assembly.Panel`: scikit-fem's
        matrices at the truth, sensors and excitation), ``H`` (the FRF before the noise, shape (N_LINES,
        n_sensors), complex, m/N), ``omega2`` and ``phi`` (the modes kept, :func:`.synthesis.lowest_modes`).
    """
    from . import geometry
    from .assembly import assemble_panel
    from .synthesis import Cholesky, lowest_modes, modal_frf

    stages: dict[str, float] = {}
    t0 = time.perf_counter()

    def stage(name: str, since: float) -> float:
        now = time.perf_counter()
        stages[name] = round(now - since, 1)
        log.info("%s: %.1f s (peak memory %.2f GB so far)", name, now - since, peak_gb())
        return now

    out.mkdir(parents=True, exist_ok=True)
    text = TEMPLATE.read_text()
    spec = tomllib.loads(text)
    points = np.array([s["point"] for s in spec["sensors"]] + [e["point"] for e in spec["excitations"]])
    names = [seg["set"] for seg in spec["segments"]]
    if names != list(geometry.SEGMENTS):
        raise ValueError(f"{TEMPLATE}: segments {names} are not the geometry's {list(geometry.SEGMENTS)}")
    size = geometry.size_for_dofs(dofs) if size is None else size
    mesh = out / spec["mesh"]
    info = geometry.build(mesh, size, points, per_circle or geometry.PER_CIRCLE)
    shutil.copyfile(TEMPLATE, out / "model.toml")
    t = stage("mesh", t0)

    alpha = true_factors(len(names))
    panel = assemble_panel(spec, mesh, alpha, None if point_mass is None else (mass_at, point_mass))
    log.info("scikit-fem: %d cells, %d free DOFs, K %d nonzeros", panel.n_cells, panel.n_dofs, panel.K.nnz)
    t = stage("assembly", t)

    freqs = frequencies()
    cutoff = cutoff_factor * freqs[-1]
    solve = Cholesky(panel.K)
    t = stage("factorisation", t)
    omega2, phi, omega2_next = lowest_modes(panel.K, panel.M, solve, cutoff)
    modes_hz = np.sqrt(omega2) / (2 * np.pi)
    log.info("%d modes below %.0f Hz (%.1f-%.1f Hz), next at %.1f Hz", omega2.size, cutoff, modes_hz[0],
             modes_hz[-1], np.sqrt(omega2_next) / (2 * np.pi))
    solves_modes = solve.solves
    t = stage("modes", t)
    H, series = modal_frf(panel.K, panel.M, solve, omega2, phi, panel.outputs, panel.load, freqs, panel.damping)
    solve.free()
    t = stage("frf", t)

    Z = add_noise(H)
    extra = "" if panel.mass_node is None else (f" + an undeclared point mass of {panel.mass_node['mass_kg']:.4g} kg "
                                                 f"at {panel.mass_node['xyz_m']}")
    note = (f"scikit-fem (ElementTetP2) assembly of {spec['mesh']} at the truth (truth.json){extra}, modes below "
            f"{cutoff:.0f} Hz + deflated remainder, {NOISE:.0%} complex noise (seed {NOISE_SEED}); "
            "python -m benchmarks.make.large")
    write_measured(out / "measured.csv", freqs, Z, panel.sensor_names, panel.excitation_name, note)
    truth = {
        "alpha": dict(zip(names, alpha.tolist())),
        "alpha_drawn": f"uniform in {list(ALPHA_RANGE)}, numpy default_rng({TRUTH_SEED}), rounded to 0.001",
        "noise": {"level": NOISE, "seed": NOISE_SEED,
                  "model": "Z = H (1 + level (n1 + i n2) / sqrt(2)), n1, n2 standard normal (lines x sensors)"},
        "lines": {"start_hz": F_START, "step_hz": F_STEP, "count": N_LINES},
        "damping": {"a": panel.damping[0], "b": panel.damping[1], "model": "Rayleigh C = a M + b K(alpha)"},
        "free_dofs": panel.n_dofs, "tet10_cells": panel.n_cells, "mesh_size_m": size,
        "mass_kg": round(sum(panel.segment_masses), 6),
        **({"point_mass": panel.mass_node} if panel.mass_node else {}),
        "modes": {"cutoff_hz": cutoff, "kept": int(omega2.size), "natural_hz": np.round(modes_hz, 3).tolist(),
                  "next_hz": round(float(np.sqrt(omega2_next) / (2 * np.pi)), 3)},
        "remainder": {k: (round(v, 8) if isinstance(v, float) else v) for k, v in series.items()},
        "files": {name: sha256(out / name) for name in (spec["mesh"], "measured.csv", "model.toml")},
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    generation = {
        "dofs_asked": dofs, "free_dofs": panel.n_dofs, "tet10_cells": panel.n_cells, "nodes": info["nodes"],
        "mesh_size_m": size, "modes_kept": int(omega2.size), "solves": {"modes": solves_modes,
                                                                         "remainder": solve.solves - solves_modes},
        "stages_s": stages, "wall_s": round(time.perf_counter() - t0, 1), "peak_memory_gb": round(peak_gb(), 2),
        "file_mb": {p.name: round(p.stat().st_size / 1e6, 2) for p in sorted(out.iterdir())},
    }
    (out / "generation.json").write_text(json.dumps(generation, indent=1) + "\n")
    log.info("wrote %s: %s", out, ", ".join(f"{k} {v} MB" for k, v in generation["file_mb"].items()))
    return {"generation": generation, "panel": panel, "H": H, "omega2": omega2, "phi": phi}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.make.large",
                                     description="Generate the large ribbed-panel example at about N free DOFs.")
    parser.add_argument("--dofs", type=float, required=True, help="about this many free DOFs (e.g. 150000)")
    parser.add_argument("--out", type=Path, help="folder to write (default data/examples/large/<N/1000>k)")
    parser.add_argument("--size", type=float, help="mesh size, m, instead of the one for --dofs")
    parser.add_argument("--per-circle", type=int, help="elements per circle on the holes")
    parser.add_argument("--cutoff-factor", type=float, default=CUTOFF_FACTOR,
                        help=f"keep modes up to this times the band's top (default {CUTOFF_FACTOR})")
    parser.add_argument("--point-mass", type=float, metavar="SHARE",
                        help="the measured panel carries an undeclared point mass of SHARE times its mass "
                             "(e.g. 0.03; the closure's case)")
    parser.add_argument("--mass-at", type=float, nargs=3, default=MASS_AT, metavar=("X", "Y", "Z"),
                        help=f"where, m (the nearest node; default {MASS_AT})")
    args = parser.parse_args(argv)
    if args.dofs < 1000:
        parser.error("--dofs must be at least 1000")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    logging.getLogger("skfem").setLevel(logging.WARNING)
    out = args.out or OUT / f"{round(args.dofs / 1000)}k"
    generation = generate(args.dofs, out, args.size, args.per_circle, args.cutoff_factor, args.point_mass,
                          args.mass_at)["generation"]
    print(json.dumps(generation, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
