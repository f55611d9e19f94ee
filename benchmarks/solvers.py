"""Sparse factorisations for unstructured meshes, measured on the L-bracket tet10 mesh.

    nice -n 5 python -m benchmarks.solvers [--mesh data/examples/bracket/bracket.msh]

For each candidate, in its own subprocess (one BLAS/MKL thread, so the memory
is the candidate's own): the time to factor the stiffness K of
the free DOFs (symmetric positive-definite), the time of one solve with one
right-hand side and with 8 (the Krylov FRF makes one single-column solve per basis
vector), the relative residual, the resident memory held by the
factorisation, and the whole 12-frequency Krylov FRF with the candidate in place of
:func:`fe_core.solvers.frf.spd_solver`. The direct FRF's complex ``K - w^2 M + j w C`` is
measured for the factorisations that take complex matrices. Writes ``docs/results/solvers.md``.
CHOLMOD is optional here (``pip install scikit-sparse==0.4.16`` with Debian's
libsuitesparse-dev); a candidate that fails to import is reported and skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

CANDIDATES = {
    "cholmod": "CHOLMOD supernodal Cholesky (scikit-sparse 0.4.16, SuiteSparse 5.12, AMD/METIS)",
    "pardiso": "MKL PARDISO, SPD mode (pypardiso 0.4.7)",
    "splu-colamd": "SciPy SuperLU, COLAMD ordering (scipy's default)",
    "splu-mmd": "SciPy SuperLU, MMD on A^T + A",
    "spsolve": "scipy.sparse.linalg.spsolve (SuperLU, refactors per call)",
    "banded-rcm": "LAPACK banded Cholesky after reverse Cuthill-McKee (the benchmark's solver)",
    "complex-splu-colamd": "complex K - w^2 M + j w C, SuperLU COLAMD (direct FRF today)",
    "complex-splu-mmd": "complex K - w^2 M + j w C, SuperLU MMD on A^T + A",
}


def _resident_mb() -> float:
    """Current resident set of this process, MB (Linux)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def factorizer(name: str):
    """``factor(A) -> solve`` for one candidate."""
    import scipy.sparse.linalg as spla

    if name == "cholmod":
        from sksparse.cholmod import cholesky

        return lambda A: cholesky(A.tocsc()).solve_A
    if name == "pardiso":
        from fe_core.solvers.frf import spd_solver

        return spd_solver
    if name.endswith("splu-colamd"):
        return lambda A: spla.splu(A.tocsc(), permc_spec="COLAMD").solve
    if name.endswith("splu-mmd"):
        return lambda A: spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A").solve
    if name == "spsolve":
        return lambda A: (lambda rhs: spla.spsolve(A.tocsc(), rhs))
    if name == "banded-rcm":
        return _banded_rcm
    raise ValueError(name)


def _banded_rcm(A):
    from scipy.linalg import lapack
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    perm = reverse_cuthill_mckee(A.tocsr(), symmetric_mode=True)
    P = A.tocsr()[perm][:, perm].tocoo()
    upper = P.row <= P.col
    band = int(np.max(P.col[upper] - P.row[upper]))
    ab = np.zeros((band + 1, A.shape[0]))
    ab[band + P.row[upper] - P.col[upper], P.col[upper]] = P.data[upper]
    factor, info = lapack.dpbtrf(ab, lower=0, overwrite_ab=1)
    if info != 0:
        raise RuntimeError(f"dpbtrf info={info}")
    inverse = np.argsort(perm)
    return lambda rhs: lapack.dpbtrs(factor, rhs[perm], lower=0)[0][inverse]


def measure(name: str, mesh: Path) -> dict:
    """Factor and solve with one candidate; times in s, memory held by the factor in MB.

    For the real candidates also the whole 12-frequency Krylov FRF of the bracket with
    this factorisation in place of :func:`fe_core.solvers.frf.spd_solver`.
    """
    from unittest import mock

    from benchmarks.bracket import DAMPING, FREQUENCIES_HZ, problem
    from fe_core.solvers import frf

    prob = problem(mesh)
    A = prob.K.tocsc()
    if name.startswith("complex"):
        w = 2 * np.pi * FREQUENCIES_HZ[6]
        a, b = DAMPING
        A = (prob.K - w**2 * prob.M + 1j * w * (a * prob.M + b * prob.K)).tocsc()
    factor = factorizer(name)
    rhs = np.random.default_rng(0).normal(size=(A.shape[0], 8)).astype(A.dtype)
    base = _resident_mb()
    t0 = time.perf_counter()
    solve = factor(A)
    t_factor = time.perf_counter() - t0 if name != "spsolve" else None
    memory = _resident_mb() - base
    t0 = time.perf_counter()
    x1 = solve(rhs[:, 0])
    t_one = time.perf_counter() - t0
    t0 = time.perf_counter()
    x8 = solve(rhs)
    t_eight = time.perf_counter() - t0
    residual = max(
        float(np.linalg.norm(A @ x1.ravel() - rhs[:, 0]) / np.linalg.norm(rhs[:, 0])),
        float(np.linalg.norm(A @ x8 - rhs) / np.linalg.norm(rhs)),
    )
    del solve
    t_frf = dimension = None
    if not name.startswith("complex") and name != "spsolve":
        omegas = frf.hz_to_rad(FREQUENCIES_HZ)
        with mock.patch.object(frf, "spd_solver", factor):
            t0 = time.perf_counter()
            _, info = frf.krylov_frf(prob.K, prob.M, *DAMPING, prob.F, omegas, prob.out_dofs, return_info=True)
            t_frf = time.perf_counter() - t0
        dimension = info.dimension
    return {
        "name": name, "n": A.shape[0], "nnz": int(prob.K.nnz), "factor_s": t_factor, "solve1_s": t_one,
        "solve8_s": t_eight, "residual": residual, "memory_mb": memory, "krylov_frf_s": t_frf,
        "krylov_dimension": dimension,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", type=Path, default=Path("data/examples/bracket/bracket.msh"))
    parser.add_argument("--one", choices=sorted(CANDIDATES), help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path("docs/results/solvers.md"))
    parser.add_argument("--only", nargs="*", choices=sorted(CANDIDATES))
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(measure(args.one, args.mesh)))
        return 0
    rows = []
    for name in args.only or CANDIDATES:
        command = [sys.executable, "-m", "benchmarks.solvers", "--one", name, "--mesh", str(args.mesh)]
        done = subprocess.run(command, capture_output=True, text=True, timeout=900)
        if done.returncode != 0:
            print(f"{name}: failed\n{done.stderr[-2000:]}", file=sys.stderr)
            continue
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(json.dumps(row), flush=True)

    def fmt(v, unit=""):
        return "-" if v is None else f"{v:.3g}{unit}"

    lines = [
        f"# Sparse factorisations on the L-bracket tet10 mesh ({rows[0]['n']} free DOFs, nnz(K) = {rows[0]['nnz']})",
        "",
        "`nice -n 5 python -m benchmarks.solvers` (one thread each, one subprocess per candidate; "
        "memory is the growth of the resident set held by the factorisation; the Krylov FRF is the whole "
        "12-frequency `krylov_frf` of `benchmarks/bracket.py` with this factorisation of K).",
        "",
        "| candidate | factor (s) | solve, 1 rhs (s) | solve, 8 rhs (s) | residual | memory (MB) "
        "| Krylov FRF (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {CANDIDATES[row['name']]} | {fmt(row['factor_s'])} | {fmt(row['solve1_s'])} | "
            f"{fmt(row['solve8_s'])} | {row['residual']:.1e} | {row['memory_mb']:.0f} "
            f"| {fmt(row['krylov_frf_s'])} |"
        )
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
