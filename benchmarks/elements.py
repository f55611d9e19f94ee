"""Speed of the tet10 element family on the L-bracket example (docs/results/elements.md).

    nice -n 5 python -m benchmarks.elements [--mesh data/examples/bracket/bracket.msh]

One BLAS/MKL thread. Measured in one run:

* assembly of K and M (element matrices and the sparse sum) against scikit-fem's for
  the same mesh (``MeshTet2`` from meshio: the same curved quadratic cells; stiffness
  with the degree-2 rule and mass with degree 4, as ours), median of ``--repeats``;
  reading the file is excluded from both;
* one FRF at 12 frequencies with the Krylov method (PARDISO Cholesky of K, the bracket
  bolted at its holes, a unit load, 9 outputs; :mod:`benchmarks.bracket`) against the
  reference, one complex SuperLU per frequency, and their largest difference relative
  to the largest response;
* the peak resident memory of the process after each stage.

Writes ``docs/results/elements.md``. Nothing here is asserted: the tests check correctness.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import resource
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

from benchmarks.bracket import (  # noqa: E402
    BRACKET,
    DAMPING,
    E,
    FREQUENCIES_HZ,
    NU,
    RHO,
    element_matrices,
    problem,
    read,
    volume_cells,
)
from benchmarks.timing import median_time  # noqa: E402
from fe_core.solvers import frf  # noqa: E402
from fe_core.assembly import assemble  # noqa: E402

log = logging.getLogger("benchmarks.elements")


def peak_mb() -> float:
    """Peak resident set of this process so far, MB (Linux reports KB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def ours(mesh):
    cell_type, cells = volume_cells(mesh)
    n = 3 * mesh.points.shape[0]
    dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(cells.shape[0], -1)
    Ke, Me = element_matrices(mesh.points, cell_type, cells)
    return assemble(Ke, dofs, n), assemble(Me, dofs, n)


def scikit_fem(sk_mesh):
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    @skfem.BilinearForm
    def mass(u, v, w):
        return RHO * skfem.helpers.dot(u, v)

    element = skfem.ElementVector(skfem.ElementTetP2())
    K = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), skfem.Basis(sk_mesh, element, intorder=2))
    M = skfem.asm(mass, skfem.Basis(sk_mesh, element, intorder=4))
    return K, M


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", type=Path, default=BRACKET / "bracket.msh")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("docs/results/elements.md"))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("skfem").setLevel(logging.WARNING)

    from skfem.io.meshio import from_meshio

    mesh = read(args.mesh)
    sk_mesh = from_meshio(mesh)
    _, cells = volume_cells(mesh)
    log.info("%s: %d tet10 cells, %d DOFs", args.mesh.name, len(cells), 3 * len(mesh.points))
    t_ours = median_time(lambda: ours(mesh), args.repeats)
    t_sk = median_time(lambda: scikit_fem(sk_mesh), args.repeats)
    K, M = ours(mesh)
    K_sk, M_sk = scikit_fem(sk_mesh)
    # Same matrices up to DOF numbering: compare sums that do not depend on it.
    trace_rdiff = max(abs(K.diagonal().sum() / K_sk.diagonal().sum() - 1), abs(M.sum() / M_sk.sum() - 1))
    mem_assembly = peak_mb()
    log.info("assembly: ours %.3f s, scikit-fem %.3f s", t_ours, t_sk)

    prob = problem(args.mesh)
    omegas = frf.hz_to_rad(FREQUENCIES_HZ)
    a, b = DAMPING
    t_fast = median_time(lambda: frf.krylov_frf(prob.K, prob.M, a, b, prob.F, omegas, prob.out_dofs), 3)
    fast, info = frf.krylov_frf(prob.K, prob.M, a, b, prob.F, omegas, prob.out_dofs, return_info=True)
    mem_krylov = peak_mb()
    log.info("Krylov FRF %.2f s (dimension %d); direct reference next", t_fast, info.dimension)
    t0 = time.perf_counter()
    ref = frf.direct_frf(prob.K, prob.M, a * prob.M + b * prob.K, prob.F, omegas, prob.out_dofs)
    t_direct = time.perf_counter() - t0
    mem_direct = peak_mb()
    rdiff = float(np.max(np.abs(fast - ref)) / np.max(np.abs(ref)))
    entry_rdiff = float(np.max(np.abs(fast - ref) / np.abs(ref)))

    rows = [
        ("mesh", f"{args.mesh.name}: {len(cells)} tet10 cells, {3 * len(mesh.points)} DOFs, "
                 f"{prob.K.shape[0]} free (bolt holes fixed)", ""),
        ("assembly of K and M, ours", f"{t_ours:.3f} s", ""),
        ("assembly of K and M, scikit-fem 12 (same cells and rules)", f"{t_sk:.3f} s", ""),
        ("ours / scikit-fem", f"{t_ours / t_sk:.2f}", "<= 1"),
        ("trace(K), sum(M): ours against scikit-fem", f"{trace_rdiff:.1e}", "round-off"),
        ("FRF, Krylov (PARDISO Cholesky of K), 12 frequencies", f"{t_fast:.2f} s (space of {info.dimension})", ""),
        ("FRF, direct complex SuperLU per frequency", f"{t_direct:.1f} s", "reference"),
        ("direct / Krylov time", f"{t_direct / t_fast:.0f}x", ">= 10x"),
        ("largest difference / largest response", f"{rdiff:.1e}", "<= 1e-8"),
        ("largest entry-wise relative difference", f"{entry_rdiff:.1e}", ""),
        ("peak resident memory after assembly / Krylov / direct",
         f"{mem_assembly:.0f} / {mem_krylov:.0f} / {mem_direct:.0f} MB", ""),
    ]
    lines = [
        "# tet10 speed on the L-bracket example",
        "",
        f"`nice -n 5 python -m benchmarks.elements` (one thread; {platform.processor() or platform.machine()}, "
        f"numpy {np.__version__}; assembly median of {args.repeats}, Krylov median of 3, direct once).",
        "",
        "| metric | value | goal |",
        "|---|---|---|",
        *[f"| {m} | {v} | {g} |" for m, v, g in rows],
    ]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
