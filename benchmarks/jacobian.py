"""What an exact Jacobian costs: the Krylov projection against the direct adjoint and finite differences.

    nice -n 5 python -m benchmarks.jacobian                  # benchmark, matrices example, bracket (coarse, fine)
    python -m benchmarks.jacobian --models benchmark --repeat 5

For each model, in one process and one run (so the ratios share the machine's load):

* ``frf``: one Krylov FRF at the measurement frequencies (``model.frf``, the
  FE run of the update);
* ``krylov``: :func:`fe_core.solvers.sensitivity.frf_jacobian` with ``method="krylov"``
  (FRF and the m derivative columns on one block Krylov space from K^-1 [F, L]);
* ``direct``: the same with ``method="direct"`` (one complex sparse LU per
  frequency with 1 + n_sensors right-hand sides: the reference; skipped above
  ``--direct-max-dofs``);
* forward differences (m + 1 Krylov FRFs) and central ones (2 m), derived from ``frf``'s time.

Times are medians over ``--repeat`` calls, CPU (``time.process_time``) and wall; the load average
is printed. The accuracy columns compare the Krylov ``d ln|Z| / d alpha`` with the direct one (the
largest difference over all entries, relative to the largest entry). Writes ``docs/results/jacobian.md``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

MODELS = {
    "benchmark": "three plates, hex8, 3510 DOFs, banded Cholesky (12 frequencies, 6 sensors)",
    "matrices": "cantilever_matrices example, 675 DOFs, matrices model with a remainder (15 frequencies, 5 sensors)",
    "bracket_coarse": "L-bracket tet10 coarse mesh, 8388 DOFs, PARDISO (15 frequencies, 6 sensors)",
    "bracket": "L-bracket tet10 example mesh, 33,681 DOFs, PARDISO (15 frequencies, 6 sensors)",
}


def load(name: str):
    """``(model, alpha, freqs_hz)`` of a named case."""
    from fe_core.io import read_model

    if name == "benchmark":
        from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate

        return three_plate(), ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
    if name == "matrices":
        folder = REPO / "data" / "examples" / "cantilever_matrices"
        truth = json.loads((folder / "truth.json").read_text())
        model = read_model(folder / "model.toml")
        import pandas as pd

        freqs = np.unique(pd.read_csv(folder / "measured.csv")["frequency_hz"].to_numpy())
        return model, np.asarray(truth["alpha"], float), freqs
    folder = REPO / "data" / "examples" / "bracket"
    truth = json.loads((folder / "truth.json").read_text())
    model = read_model(folder / ("model_coarse.toml" if name == "bracket_coarse" else "model.toml"))
    return model, np.asarray(truth["alpha"], float), np.asarray(truth["frequencies_hz"], float)


def _timed(fun, repeat: int):
    cpu, wall, out = [], [], None
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        out = fun()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return float(np.median(cpu)), float(np.median(wall)), out


def measure(name: str, repeat: int, direct_max_dofs: int) -> dict:
    from fe_core.solvers.sensitivity import frf_jacobian

    model, alpha, freqs = load(name)
    model.frf(alpha, freqs)  # warm up: imports, the cached segment matrices
    frf_jacobian(model, alpha, freqs)
    row = {"model": name, "dofs": model.n_dofs, "parameters": model.n_segments, "frequencies": len(freqs),
           "sensors": model.n_sensors}
    row["frf_cpu"], row["frf_wall"], _ = _timed(lambda: model.frf(alpha, freqs), repeat)
    row["krylov_cpu"], row["krylov_wall"], (Z, dZ, info) = _timed(
        lambda: frf_jacobian(model, alpha, freqs, return_info=True), repeat)
    row["dimension"], row["solves"] = info.dimension, info.solves
    row["converged"] = bool(info.converged)
    if model.n_dofs <= direct_max_dofs:
        row["direct_cpu"], row["direct_wall"], (Zd, dZd) = _timed(
            lambda: frf_jacobian(model, alpha, freqs, method="direct"), max(1, repeat // 2))
        J, Jd = np.real(dZ / Z[:, :, None]), np.real(dZd / Zd[:, :, None])
        row["J_difference"] = float(np.abs(J - Jd).max() / np.abs(Jd).max())
        size = np.abs(Zd).max(axis=1)
        row["Z_difference"] = float((np.abs(Z - Zd).max(axis=1) / size).max())
    m = model.n_segments
    row["forward_cpu"] = (m + 1) * row["frf_cpu"]
    row["central_cpu"] = 2 * m * row["frf_cpu"]
    return row


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.1f} ms" if seconds < 10 else f"{seconds:.1f} s"


def table(rows: list[dict], load_avg: str, repeat: int) -> str:
    head = ["model", "DOFs", "m", "Krylov FRF (one FE run)", "Krylov Jacobian", "in FE runs", "space (solves)",
            "direct Jacobian", "in FE runs", "direct / Krylov", "forward differences (m + 1 FE runs)",
            "max |J_krylov - J_direct| / max |J|"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        direct = "direct_cpu" in r
        cells = [r["model"], str(r["dofs"]), str(r["parameters"]), _ms(r["frf_cpu"]), _ms(r["krylov_cpu"]),
                 f"{r['krylov_cpu'] / r['frf_cpu']:.1f}", f"{r['dimension']} ({r['solves']})",
                 _ms(r["direct_cpu"]) if direct else "skipped",
                 f"{r['direct_cpu'] / r['frf_cpu']:.0f}" if direct else "-",
                 f"{r['direct_cpu'] / r['krylov_cpu']:.1f}" if direct else "-",
                 _ms(r["forward_cpu"]), f"{r['J_difference']:.1e}" if direct else "-"]
        lines.append("| " + " | ".join(cells) + " |")
    notes = (f"\nCPU time, median of {repeat} calls (direct: of {max(1, repeat // 2)}), one BLAS thread, one "
             f"process; load average at the end {load_avg} (2 cores shared with other work). 'in FE runs': the "
             "Jacobian's CPU time over one Krylov FRF's. 'space (solves)': the Krylov space's dimension when the "
             "FRF and the derivatives stopped changing (1e-10 and 1e-8) and the right-hand sides solved with the "
             "one real factorisation.\n")
    return "\n".join(lines) + "\n" + notes


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.jacobian", description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="+", choices=list(MODELS), default=list(MODELS))
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--direct-max-dofs", type=int, default=10_000,
                   help="skip the direct Jacobian above this many DOFs (minutes per call on the fine bracket)")
    p.add_argument("--out", default=str(REPO / "docs" / "results" / "jacobian.md"))
    args = p.parse_args(argv)
    rows = []
    for name in args.models:
        print(f"{name}: {MODELS[name]} ...", flush=True)
        rows.append(measure(name, args.repeat, args.direct_max_dofs))
        print(json.dumps(rows[-1]), flush=True)
    load_avg = " ".join(Path("/proc/loadavg").read_text().split()[:3])
    command = " ".join(["python -m benchmarks.jacobian"] + (sys.argv[1:] if argv is None else list(argv)))
    text = (f"Command: `{command}`\n\n"
            "Cost of one exact Jacobian d ln|Z| / d alpha (fe_core.solvers.sensitivity.frf_jacobian) against one FE "
            "run. Models: " + "; ".join(f"{k}: {MODELS[k]}" for k in args.models) + ".\n\n"
            + table(rows, load_avg, args.repeat))
    print(text)
    Path(args.out).write_text(text)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
