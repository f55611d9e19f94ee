"""The transient memory of the reduced basis's enrichment (issue 41): how much a new space costs beyond V.

    python -m benchmarks.basis_memory [--dofs 200000] [--columns 143]

A basis of ``--columns`` columns at ``--dofs`` DOFs (ten segment parts, a 40-row sketch, a capacity of three
spaces), then a second space of as many columns added to it (:meth:`ParametricBasis.extend`), its peak of
allocated memory traced (``tracemalloc``: numpy's and LAPACK's work arrays allocated through numpy count). The
figure is printed as a multiple of the new space itself (n x columns doubles), so it holds at any size: at
500k DOFs a space of 143 columns is 0.57 GB. The parts are a tridiagonal stand-in: the temporaries of the
projection are n x columns whatever the matrices' fill. Run from another checkout (``git worktree``) for the
figure of another commit.
"""

from __future__ import annotations

import argparse
import json
import tracemalloc

import numpy as np
import scipy.sparse as sp

from fe_core.solvers import reduced_basis as rb


def measure(n: int, s: int, parts: int = 10, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    A = sp.diags([np.full(n - 1, -1.0), np.full(n, 2.0), np.full(n - 1, -1.0)], [-1, 0, 1], format="csr")
    basis = rb.ParametricBasis([A] * parts, [], rng.standard_normal((n, 1)), rng.standard_normal((n, 8)),
                               lambda X: X, sketch=rb.sparse_sign_sketch(n), capacity=3 * s)
    basis.extend(rng.standard_normal((n, s)))
    W = rng.standard_normal((n, s))
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    added = basis.extend(W)
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    return {"dofs": n, "columns": s, "added": added, "peak_bytes": peak,
            "peak_over_space": round(peak / (8.0 * n * s), 2)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dofs", type=int, default=200_000)
    p.add_argument("--columns", type=int, default=143)
    args = p.parse_args(argv)
    print(json.dumps(measure(args.dofs, args.columns)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
