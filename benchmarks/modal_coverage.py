"""Coverage of the modal update's 95 % intervals over noisy data sets (issue 31).

    nice -n 10 python -m benchmarks.modal_coverage                       # 20 sets, EMA and OMA, "spec" data
    nice -n 10 python -m benchmarks.modal_coverage --source finer --sets 10

Each set: the benchmark at 18 test nodes (data/examples/modal/model.toml), the 6 modes of the reference
(:func:`benchmarks.make.modal_example.reference_modes`: ``spec`` = the SPEC's independent frequencies and
the SPEC mesh's shapes; ``finer`` = a twice finer mesh, which adds the benchmark mesh's discretisation
error) at the actual alpha, with 0.2 % frequency and 2 % shape noise (seeds 100..), fitted with stated
uncertainties from the nominal model (one start). Cases: ``ema`` (6 modes, mass-normalised shapes) and
``oma`` (shapes scaled at random, mode 5 missing). Prints, per case, how many of the 6 x N factors lie in
their intervals, per parameter too, the mean sd, FE runs and seconds per fit, and how many lie inside
when the same noise draws go through the model linearised at the truth (95 % in distribution to first order: what
the draws alone give); writes
``<out>/modal_coverage.json``. A factor inside with probability 0.95 gives 114 +- 5 of 120.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.make.modal_example import OUT, as_modes, noisy, reference_modes
from fe_core.benchmark import ALPHA_ACTUAL
from fe_core.modal_update import fit_modes
from tasks import modal
from tasks.modal_data import match_modes
from tasks.problem import read_model_ref


def run(source="spec", sets=20, cases=("ema", "oma"), sigma_f=0.002, sigma_s=0.02) -> dict:
    model, _ = read_model_ref(str(OUT / "model.toml"))
    freqs, shapes = reference_modes(source)
    out = {}
    for case in cases:
        inside, sds, runs, secs, linear = [], [], [], [], []
        for k in range(sets):
            f, s = noisy(freqs, shapes, seed=100 + k)
            if case == "oma":
                rng = np.random.default_rng(1000 + k)
                keep = [0, 1, 2, 3, 5]
                measured = as_modes(f, s, keep, rng.choice([-1, 1], 5) * rng.uniform(0.1, 10, 5))
            else:
                measured = as_modes(f, s)
            data = match_modes(measured, model)
            residual = modal.modal_residual(data, model, measured.n_modes + modal.N_EXTRA_MODES, sigma_f, sigma_s,
                                            0.6)
            t0 = time.perf_counter()
            residual.set_active(np.zeros(6))
            fit = fit_modes(residual, np.full(6, -0.95), np.ones(6), n_starts=1, stated=True)
            secs.append(time.perf_counter() - t0)
            inside.append(((fit.lower95 <= ALPHA_ACTUAL) & (ALPHA_ACTUAL <= fit.upper95)).tolist())
            # the same noise draws through the model linearised at the truth: N(0, 1) per factor to first order
            at_truth = residual.evaluate(ALPHA_ACTUAL)
            J = at_truth["J"]
            z = -np.linalg.solve(J.T @ J, J.T @ at_truth["r"]) / np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
            linear.append((np.abs(z) <= 1.959963984540054).tolist())
            sds.append(fit.sd.tolist())
            runs.append(fit.n_fe_runs)
            print(f"{case} set {k}: inside {sum(inside[-1])}/6, |error|/sd "
                  f"{np.round(np.abs(fit.theta - ALPHA_ACTUAL) / fit.sd, 2).tolist()}, {fit.n_fe_runs} FE runs, "
                  f"{secs[-1]:.1f} s", flush=True)
        inside_a = np.array(inside)
        out[case] = {"inside": int(inside_a.sum()), "of": int(inside_a.size),
                     "per_parameter": inside_a.sum(axis=0).tolist(), "mean_sd": np.mean(sds, axis=0).tolist(),
                     "fe_runs_mean": float(np.mean(runs)), "seconds_mean": float(np.mean(secs)),
                     "linearised_inside": int(np.sum(linear))}
        print(f"{case}: {out[case]['inside']}/{out[case]['of']} inside; per parameter "
              f"{out[case]['per_parameter']} of {sets}; mean sd {np.round(out[case]['mean_sd'], 4).tolist()}; "
              f"{out[case]['fe_runs_mean']:.1f} FE runs, {out[case]['seconds_mean']:.1f} s per fit; the model "
              f"linearised at the truth with the same draws: {out[case]['linearised_inside']}/{out[case]['of']} "
              "inside", flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.modal_coverage")
    p.add_argument("--source", choices=("spec", "finer"), default="spec")
    p.add_argument("--sets", type=int, default=20)
    p.add_argument("--cases", nargs="+", default=["ema", "oma"])
    p.add_argument("--frequency-sigma", type=float, default=0.002)
    p.add_argument("--out", default="runs/modal-coverage")
    args = p.parse_args(argv)
    result = run(args.source, args.sets, tuple(args.cases), args.frequency_sigma)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"modal_coverage_{args.source}.json").write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
