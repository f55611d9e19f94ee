"""Route B (ccx as a black box) on shell thicknesses: FE runs, rounds and wall time to the optimum.

    nice -n 10 python -m benchmarks.calculix_route_b

The example's cylindrical panel (benchmarks/make/shell_panel.py) on a 6 x 6 S8R mesh, four thickness
factors, truth [0.03, -0.04, 0.05, -0.03], the measured FRF ccx's own at the truth with 1 % noise (seed 3),
12 frequencies around the first three modes, 7 sensors. Each FE run is one ccx process (one thread):
the deck written into its own folder, 20 modes, one steady-state step per frequency.

* hybrid-FD: :func:`fe_core.io.calculix.blackbox.fd_gauss_newton` (one parallel round of m + 1 runs per
  Jacobian, one run per trial step), with 1 and 2 ccx processes at a time;
* DFO-LS (``dfols.solve``, its default interpolation model, sequential runs), the same residual and box.

The paper's loop and the Dask cluster are not measured here (the flows do not run decks yet).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.make import shell_panel
from fe_core.io.calculix import read_deck
from fe_core.io.calculix.blackbox import DeckFRF, fd_gauss_newton
from fe_core.io.calculix.deck import NumberRef

TRUTH = np.array([0.03, -0.04, 0.05, -0.03])


def model(folder: Path) -> DeckFRF:
    cards, ids = shell_panel.panel(6, 6)
    (folder / "panel.inp").write_text(cards)
    deck = read_deck(folder / "panel.inp")
    numbers = [NumberRef(deck.section_of(s), 0, 0) for s in shell_panel.SEGMENTS]
    sensors = [(ids[shell_panel.point(u, v)], "xyz".index(d)) for u, v, d in shell_panel.SENSORS]
    freqs = np.array([f * r for f in (71.4, 83.2, 187.0) for r in (0.85, 0.92, 1.08, 1.15)])
    return DeckFRF(deck, numbers, sensors, (deck.nsets["TIP_CORNER"][0], 2), shell_panel.DAMPING, freqs, n_modes=20)


def main() -> None:
    import dfols

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        m = model(tmp)
        Z = m.run(TRUTH, tmp / "truth")
        rng = np.random.default_rng(3)
        u = np.abs(Z) * (1 + 0.01 * rng.standard_normal(Z.shape))
        rows = []
        for workers in (1, 2):
            t0 = time.perf_counter()
            r = fd_gauss_newton(m, u, np.zeros(4), -0.3, 0.3, tmp / f"fd{workers}", workers=workers)
            rows.append((f"hybrid-FD, {workers} ccx at a time", r.fe_runs, r.rounds, time.perf_counter() - t0,
                         np.max(np.abs(r.theta - TRUTH)), float(r.residual @ r.residual)))
        count = [0]

        def residual(theta):
            count[0] += 1
            return np.log(np.abs(m.run(theta, tmp / f"dfols/run-{count[0]}"))).ravel() - np.log(u).ravel()

        t0 = time.perf_counter()
        sol = dfols.solve(residual, np.zeros(4), bounds=(-0.3 * np.ones(4), 0.3 * np.ones(4)), rhobeg=0.05,
                          rhoend=1e-5, maxfun=200)
        rows.append(("DFO-LS (sequential)", count[0], count[0], time.perf_counter() - t0,
                     np.max(np.abs(sol.x - TRUTH)), float(sol.resid @ sol.resid)))
    print("| method | FE runs | rounds | wall s | max factor error | sum r^2 |")
    print("|---|---|---|---|---|---|")
    for name, runs, rounds, wall, err, f in rows:
        print(f"| {name} | {runs} | {rounds} | {wall:.1f} | {err:.4f} | {f:.5f} |")


if __name__ == "__main__":
    import argparse

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    main()
