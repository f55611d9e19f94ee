"""How often the shell example's 95 % intervals cover the truth: K noise draws on the same exact FRF.

    nice -n 10 python -m benchmarks.shell_panel_coverage [--draws 10] [--first-seed 100]

The exact FRF is ``data/examples/shell_panel/exact.npz`` (ccx's matrices of the 40 x 40 data mesh at the true
factors, solved directly; ``python -m benchmarks.make.shell_panel``). Each draw multiplies it by
1 + 0.01 N(0, 1) (seeds first-seed, first-seed + 1, ...), and route A's 20 x 20 model is fitted from the
nominal factors by Gauss-Newton with exact Jacobians (:func:`fe_core.inference.intervals.parameter_intervals`,
the intervals the flow reports), with the noise estimated from the residual as the flow does. Printed: each
draw's factors, interval half-widths and whether they cover the truth, then the coverage rate per factor and
over all of them (95 % expected; with 4 x K intervals, a rate below about 85 % would say the intervals are
too narrow).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "examples" / "shell_panel"


def main(draws: int = 10, first_seed: int = 100) -> dict:
    from fe_core.inference.intervals import parameter_intervals
    from fe_core.io import read_model

    truth = json.loads((EXAMPLE / "truth.json").read_text())
    alpha_true = np.array(truth["parameters"])
    exact = np.load(EXAMPLE / "exact.npz")
    freqs, amplitude = exact["frequencies_hz"], np.abs(exact["frf"])
    model = read_model(EXAMPLE / "model.toml")
    covered, errors, rows = [], [], []
    for k in range(draws):
        seed = first_seed + k
        rng = np.random.default_rng(seed)
        noisy = amplitude * (1 + truth["noise"] * rng.standard_normal(amplitude.shape))
        t0 = time.perf_counter()
        fit = parameter_intervals(model, freqs, noisy, np.zeros(alpha_true.size), -0.5, 0.5, noise=None,
                                  max_jacobians=8).intervals
        inside = (fit.low <= alpha_true) & (alpha_true <= fit.high)
        covered.append(inside)
        errors.append(fit.estimate - alpha_true)
        rows.append({"seed": seed, "estimate": fit.estimate.round(5).tolist(),
                     "half_width": ((fit.high - fit.low) / 2).round(5).tolist(), "covers": inside.tolist(),
                     "seconds": round(time.perf_counter() - t0, 1)})
        print(f"seed {seed}: alpha = {np.round(fit.estimate, 4).tolist()} +/- "
              f"{np.round((fit.high - fit.low) / 2, 4).tolist()}, covers {inside.tolist()}, "
              f"max error {np.max(np.abs(errors[-1])):.4f} ({rows[-1]['seconds']} s)", flush=True)
    covered = np.array(covered)
    rate = covered.mean(axis=0)
    print(f"coverage per factor over {draws} draws: {rate.round(2).tolist()}; over all {covered.size} intervals: "
          f"{covered.mean():.2f} (95 % expected); max |error| {np.max(np.abs(errors)):.4f}")
    return {"draws": rows, "coverage_per_factor": rate.tolist(), "coverage": float(covered.mean()),
            "max_abs_error": float(np.max(np.abs(errors)))}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=10, help="noise draws (default 10)")
    parser.add_argument("--first-seed", type=int, default=100, help="seed of the first draw (default 100)")
    args = parser.parse_args()
    main(args.draws, args.first_seed)
