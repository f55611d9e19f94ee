"""Sparse factorisations for unstructured meshes, measured on the L-bracket tet10 mesh.

    nice -n 5 python -m benchmarks.solvers [--mesh data/examples/bracket/bracket.msh]

For each candidate, in its own subprocess (one BLAS/MKL thread, so the peak
resident memory is the candidate's own): the time to factor the stiffness K of
the free DOFs (symmetric positive-definite), the time of one solve with one
right-hand side and with 8 (the Krylov FRF makes one single-column solve per basis
vector), the relative residual, and the growth of the peak resident set during the
factorisation. The direct FRF's complex ``K - w^2 M + j w C`` is measured for the
factorisations that take complex matrices. Writes ``docs/solvers.md``.
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


def _rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(name: str, mesh: Path) -> dict:
    """Factor and solve with one candidate; returns times (s), residual and memory (MB)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from benchmarks.bracket import DAMPING, FREQUENCIES_HZ, problem

    prob = problem(mesh)
    K = prob.K.tocsc()
    A = K
    if name.startswith("complex"):
        w = 2 * np.pi * FREQUENCIES_HZ[6]
        a, b = DAMPING
        A = (K - w**2 * prob.M + 1j * w * (a * prob.M + b * K)).tocsc()
    rng = np.random.default_rng(0)
    B = rng.normal(size=(K.shape[0], 8))
    base = _rss_mb()
    t0 = time.perf_counter()
    if name == "cholmod":
        from sksparse.cholmod import cholesky

        factor = cholesky(A)
        solve = factor.solve_A
    elif name == "pardiso":
        from pypardiso import PyPardisoSolver

        solver = PyPardisoSolver(mtype=2)  # real symmetric positive-definite
        upper = sp.triu(A, format="csr")
        solver.factorize(upper)

        def solve(rhs):
            return solver.solve(upper, rhs)
    elif name.endswith("splu-colamd"):
        solve = spla.splu(A, permc_spec="COLAMD").solve
    elif name.endswith("splu-mmd"):
        solve = spla.splu(A, permc_spec="MMD_AT_PLUS_A").solve
    elif name == "spsolve":
        def solve(rhs):
            return spla.spsolve(A, rhs)
    elif name == "banded-rcm":
        from scipy.linalg import lapack
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        perm = reverse_cuthill_mckee(A.tocsr(), symmetric_mode=True)
        P = A[perm][:, perm].tocoo()
        upper = P.row <= P.col
        band = int(np.max(P.col[upper] - P.row[upper]))
        ab = np.zeros((band + 1, A.shape[0]))
        ab[band + P.row[upper] - P.col[upper], P.col[upper]] = P.data[upper]
        factor, info = lapack.dpbtrf(ab, lower=0, overwrite_ab=1)
        assert info == 0
        inverse = np.argsort(perm)

        def solve(rhs):
            return lapack.dpbtrs(factor, rhs[perm], lower=0)[0][inverse]
    else:
        raise ValueError(name)
    t_factor = time.perf_counter() - t0 if name != "spsolve" else None
    memory = _rss_mb() - base
    rhs = B.astype(A.dtype)
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
    return {"name": name, "n": K.shape[0], "nnz": int(K.nnz), "factor_s": t_factor, "solve1_s": t_one,
            "solve8_s": t_eight, "residual": residual, "memory_mb": memory}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", type=Path, default=Path("data/examples/bracket/bracket.msh"))
    parser.add_argument("--one", choices=sorted(CANDIDATES), help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path("docs/solvers.md"))
    parser.add_argument("--only", nargs="*", choices=sorted(CANDIDATES))
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(measure(args.one, args.mesh)))
        return 0
    rows = []
    for name in args.only or CANDIDATES:
        done = subprocess.run([sys.executable, "-m", "benchmarks.solvers", "--one", name, "--mesh", str(args.mesh)],
                              capture_output=True, text=True, timeout=900)
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
        "memory is the growth of the peak resident set while factoring).",
        "",
        "| candidate | factor (s) | solve, 1 rhs (s) | solve, 8 rhs (s) | residual | memory (MB) |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {CANDIDATES[row['name']]} | {fmt(row['factor_s'])} | {fmt(row['solve1_s'])} | "
            f"{fmt(row['solve8_s'])} | {row['residual']:.1e} | {row['memory_mb']:.0f} |"
        )
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
