"""Where to put the bracket's sensors: the parameter error each layout leaves, predicted before any update.

    nice -n 5 python -m benchmarks.bracket_sensors      # docs/results/bracket-sensors.md (about 10 min, 3.5 GB)

Example (a) updates the default tet10 mesh from the FRF of a finer one. What the update can reach is
limited twice: by the noise (1 %) and by the discretisation residual ``r = ln|Z_default(truth)| -
ln|Z_fine(truth)|`` (8 % overall error at the truth), which least squares absorbs through the factors.
Linearised at the truth with the default mesh's exact log-amplitude Jacobian ``J``
(:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian`), a layout S of sensors ends at

    alpha_S - alpha_true = -(J_S^T J_S)^-1 J_S^T r_S      (the bias), std 0.01 sqrt(diag (J_S^T J_S)^-1)

so every layout of the candidate sensors below can be judged from one Jacobian of the default mesh and
one FRF of the fine mesh at the truth, both at the measured frequencies (``truth.json``) and with the
example's hammer. The script prints the layout of the example, the best layouts of 6, 7 and 8 sensors
(exhaustive over the candidates) and writes ``docs/results/bracket-sensors.md``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.make import bracket_example as mb  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs" / "results"
CACHE = REPO / "runs" / "bracket-sensors"

#: Candidate sensors (name, point [m], direction), on the surface of both meshes. The ribs' hypotenuse is
#: x + z = 0.07 m (normal (1, 0, 1)); their outer faces are y = 0 and y = 0.08 m.
CANDIDATES = (
    ("web top x", [0.0, 0.0, 0.12], '"x"'),
    ("web top y", [0.01, 0.08, 0.12], '"y"'),
    ("web middle x", [0.0, 0.04, 0.08], '"x"'),
    ("rib left y", [0.03, 0.0, 0.03], '"y"'),
    ("rib right normal", [0.035, 0.076, 0.035], "[1.0, 0.0, 1.0]"),
    ("foot z", [0.06, 0.04, 0.01], '"z"'),
    ("rib left normal", [0.035, 0.004, 0.035], "[1.0, 0.0, 1.0]"),
    ("rib right y", [0.03, 0.08, 0.03], '"y"'),
    ("rib left normal high", [0.02, 0.004, 0.05], "[1.0, 0.0, 1.0]"),
    ("rib right normal high", [0.02, 0.076, 0.05], "[1.0, 0.0, 1.0]"),
    ("rib left normal low", [0.05, 0.004, 0.02], "[1.0, 0.0, 1.0]"),
    ("rib right normal low", [0.05, 0.076, 0.02], "[1.0, 0.0, 1.0]"),
    ("web lower x", [0.0, 0.04, 0.04], '"x"'),
    ("web lower x low", [0.0, 0.04, 0.025], '"x"'),
    ("web lower y", [0.005, 0.0, 0.04], '"y"'),
    ("web upper x", [0.0, 0.04, 0.1], '"x"'),
    ("web top z", [0.005, 0.04, 0.12], '"z"'),
    ("web top x right", [0.0, 0.08, 0.12], '"x"'),
    ("foot inner z", [0.035, 0.04, 0.01], '"z"'),
    ("foot outer z", [0.11, 0.04, 0.01], '"z"'),
    ("foot outer z edge", [0.12, 0.0, 0.005], '"z"'),
    ("foot inner z edge", [0.04, 0.0, 0.005], '"z"'),
    ("foot x end", [0.12, 0.04, 0.005], '"x"'),
    ("foot y side", [0.08, 0.0, 0.005], '"y"'),
)
#: The example's layout before this study (benchmarks.make.bracket_example's sensors at the time).
ORIGINAL = tuple(range(6))


def _model(mesh: str, tolerance: float, folder: Path):
    from fe_core.io import read_model

    saved = mb.SENSORS
    try:
        mb.SENSORS = CANDIDATES
        text = mb.model_text(mesh, tolerance, "bracket with every candidate sensor")
    finally:
        mb.SENSORS = saved
    path = folder / f"candidates-{Path(mesh).stem}.toml"
    path.write_text(text)
    return read_model(path)


def compute(freqs: np.ndarray) -> dict:
    """J (p, n_candidates, 6) of the default mesh and both meshes' amplitudes (p, n_candidates) at the truth."""
    from fe_core.solvers.sensitivity import log_amplitude_jacobian

    CACHE.mkdir(parents=True, exist_ok=True)
    cached = CACHE / "arrays.npz"
    if cached.exists():
        data = np.load(cached)
        if data["freqs"].shape == freqs.shape and np.allclose(data["freqs"], freqs) and \
                data["J"].shape[1] == len(CANDIDATES):
            return dict(data)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        default = _model(str(mb.OUT / "bracket.msh"), mb.TOLERANCE["bracket.msh"], Path(tmp))
        J = log_amplitude_jacobian(default, mb.ALPHA_TRUE, freqs).reshape(freqs.size, len(CANDIDATES), 6)
        Zd = np.abs(default.frf(mb.ALPHA_TRUE, freqs))
        print(f"default mesh: Jacobian and FRF of {len(CANDIDATES)} candidates in {time.perf_counter() - t0:.0f} s",
              flush=True)
        del default
        t0 = time.perf_counter()
        if not (mb.OUT / "bracket_fine.msh").exists():
            import subprocess

            subprocess.run([sys.executable, str(mb.OUT / "make_mesh.py"), "--fine"], check=True)
        fine = _model(str(mb.OUT / "bracket_fine.msh"), mb.TOLERANCE["bracket_fine.msh"], Path(tmp))
        Zf = np.abs(fine.frf(mb.ALPHA_TRUE, freqs))
        print(f"fine mesh: FRF in {time.perf_counter() - t0:.0f} s", flush=True)
    out = {"freqs": freqs, "J": J, "Zd": Zd, "Zf": Zf}
    np.savez(cached, **out)
    return out


def predict(J: np.ndarray, r: np.ndarray, layout, noise: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(bias (6,), std (6,), smallest singular value) of a layout (indices of candidates)."""
    Js = J[:, list(layout), :].reshape(-1, J.shape[2])
    rs = r[:, list(layout)].ravel()
    bias = -np.linalg.lstsq(Js, rs, rcond=None)[0]
    s = np.linalg.svd(Js, compute_uv=False)
    cov = np.linalg.inv(Js.T @ Js)
    return bias, noise * np.sqrt(np.diag(cov)), float(s[-1])


def search(J, r, size: int, noise: float, keep=()) -> list[tuple[float, tuple]]:
    """Layouts of ``size`` candidates (containing ``keep``) by the largest expected |error|,
    ``max_i (|bias_i| + 2 std_i)``, best first."""
    rest = [i for i in range(len(CANDIDATES)) if i not in keep]
    scored = []
    for combo in itertools.combinations(rest, size - len(keep)):
        layout = tuple(sorted((*keep, *combo)))
        bias, std, _ = predict(J, r, layout, noise)
        scored.append((float(np.max(np.abs(bias) + 2 * std)), layout))
    return sorted(scored)


def _row(label: str, layout, J, r, noise) -> str:
    bias, std, smin = predict(J, r, layout, noise)
    cells = " | ".join(f"{b:+.3f} ({s:.3f})" for b, s in zip(bias, std))
    return (f"| {label} | {cells} | {np.max(np.abs(bias) + 2 * std):.3f} | {smin:.2f} |")


def log_optimum(start: np.ndarray, steps: int = 6, h: float = 1e-4) -> dict:
    """Gauss-Newton on the example's log-amplitude residual (model.toml, measured.csv) from ``start``, with
    forward-difference Jacobians of Krylov FE runs (the exact adjoint one needs a complex LU per frequency,
    minutes on this mesh): where the update's least-squares optimum of the log amplitudes lies."""
    from fe_core.io import read_model
    from fe_core.inference.residual import overall_error, relative_residual
    from tasks.io.measured import read_measured

    model = read_model(mb.OUT / "model.toml")
    u = read_measured(mb.OUT / "measured.csv")
    freqs, log_u = u.frequencies_hz, np.log(u.amplitude).ravel()

    def residual(a):
        return np.log(np.abs(model.frf(a, freqs))).ravel() - log_u

    x, runs = np.asarray(start, float), 1
    r = residual(x)
    for _ in range(steps):
        J = np.empty((r.size, x.size))
        for i in range(x.size):
            e = np.zeros(x.size)
            e[i] = h
            J[:, i] = (residual(x + e) - r) / h
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        r_new = residual(x + step)
        runs += x.size + 1
        if not r_new @ r_new < r @ r:
            break
        x, r = x + step, r_new
        if np.max(np.abs(step)) < 2e-4:
            break
    Z = np.abs(model.frf(x, freqs))
    return {"alpha": x, "log_rss": float(r @ r), "overall_error": overall_error(relative_residual(Z, u.amplitude)),
            "fe_runs": runs}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bracket_sensors", description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="6,7,8", help="layout sizes to search (default 6,7,8)")
    p.add_argument("--optimum", action="store_true",
                   help="only: Gauss-Newton on the example's own log residual from the truth plus its predicted bias "
                        "(data/examples/bracket: the sensors of model.toml), printed")
    args = p.parse_args(argv)
    if args.optimum:
        return _print_optimum()
    truth = json.loads((mb.OUT / "truth.json").read_text())
    freqs = np.asarray(truth["frequencies_hz"], float)
    t0, c0 = time.perf_counter(), time.process_time()
    data = compute(freqs)
    J, r = data["J"], np.log(data["Zd"]) - np.log(data["Zf"])
    noise = mb.NOISE
    head = ("| layout | " + " | ".join(mb.SEGMENTS) + " | max(|bias| + 2 std) | smallest singular value |\n"
            "|---|" + "---|" * (len(mb.SEGMENTS) + 2))
    lines = [head, _row("the example's before this study: " + ", ".join(CANDIDATES[i][0] for i in ORIGINAL),
                        ORIGINAL, J, r, noise)]
    best = {}
    for size in (int(s) for s in args.sizes.split(",")):
        ranked = search(J, r, size, noise)
        best[size] = ranked[:3]
        for k, (score, layout) in enumerate(ranked[:3]):
            lines.append(_row(f"best {size} #{k + 1}: " + ", ".join(CANDIDATES[i][0] for i in layout), layout, J, r,
                              noise))
    per_sensor = np.sqrt(np.mean(r**2, axis=0))
    text = "\n".join([
        "# Bracket sensor layouts: the parameter error each leaves, predicted",
        "",
        "`nice -n 5 python -m benchmarks.bracket_sensors` (linearised at the truth: bias = -(J^T J)^-1 J^T r from "
        "the discretisation residual r = ln|Z_default| - ln|Z_fine| at the truth, std from 1 % noise; the "
        "example's 15 frequencies and hammer). Cells: bias (std) of each alpha.",
        "",
        *lines,
        "",
        "rms discretisation residual per candidate sensor: "
        + ", ".join(f"{c[0]} {100 * v:.1f} %" for c, v in zip(CANDIDATES, per_sensor)),
        "",
        f"Computed in {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU "
        f"(load average {os.getloadavg()[0]:.1f}).",
    ])
    (DOCS / "bracket-sensors.md").write_text(text + "\n")
    print(text)
    return 0


def _print_optimum() -> int:
    """The example's layout (model.toml's sensors among the candidates): predicted and measured log optimum."""
    truth = json.loads((mb.OUT / "truth.json").read_text())
    data = compute(np.asarray(truth["frequencies_hz"], float))
    J, r = data["J"], np.log(data["Zd"]) - np.log(data["Zf"])
    names = [c[0] for c in CANDIDATES]
    layout = tuple(names.index(s[0]) for s in mb.SENSORS)
    bias, std, _ = predict(J, r, layout, mb.NOISE)
    t0, c0 = time.perf_counter(), time.process_time()
    opt = log_optimum(mb.ALPHA_TRUE + bias)
    err = opt["alpha"] - mb.ALPHA_TRUE
    print(f"layout: {', '.join(names[i] for i in layout)}")
    print(f"predicted error: {np.round(bias, 4).tolist()}")
    print(f"log optimum: {np.round(opt['alpha'], 4).tolist()}, error {np.round(err, 4).tolist()}, rms "
          f"{np.sqrt(np.mean(err**2)):.4f}; overall error {opt['overall_error']:.3%}, log rss {opt['log_rss']:.5f}; "
          f"{opt['fe_runs']} FE runs, {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
