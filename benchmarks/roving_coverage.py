"""Intervals of a roving-hammer test: coverage over noisy data sets, and the cost per reference (issue 30).

    nice -n 10 python -m benchmarks.roving_coverage              # 20 data sets, 1 % noise, ~3-5 min on 2 busy cores
    python -m benchmarks.roving_coverage --n 5 --no-cost         # a quick look

The benchmark model with one accelerometer (sensor s3, along z) and an impact hammer at each of the six
sensor points (six references, load = the sensor's output vector: a unit force at that point along z).
For each data set k (seed ``seed + k``): a true alpha uniform in ``[-TRUTH_RANGE, TRUTH_RANGE]^6``; the
six channels' receptance from the direct solver at the benchmark's 12 lines, amplitudes
``|Z| (1 + sigma e)``; the intervals of :func:`fe_core.inference.intervals.parameter_intervals` with the
channels stacked (``channels=``, what the flow's intervals stage does with several references), started
at the truth + U(-START_OFFSET, START_OFFSET), noise estimated (Student t), as a run without ``--noise``.
Prints the coverage (overall, per parameter) and the cost of one exact Jacobian with its FRF for 1, 2, 3
and 6 references (median of ``--repeat`` timings; the time of one Krylov FRF of the six sensors beside).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

LOWER, UPPER = -0.999, 1.0
TRUTH_RANGE = 0.5
START_OFFSET = 0.05
ACCELEROMETER = 2  # sensor s3


def roving_model(model=None):
    """The benchmark model with excitations ``combined`` and ``h1`` .. ``h6`` (a unit force at sensor j's point)."""
    from fe_core.benchmark import three_plate

    model = model or three_plate()
    loads = np.hstack([model.excitation_loads, model.outputs.toarray()])
    names = list(model.excitation_names) + [f"h{j + 1}" for j in range(model.n_sensors)]
    return dataclasses.replace(model, excitation_loads=loads, excitation_names=names,
                               excitation_test_dofs=list(model.excitation_test_dofs) + [None] * model.n_sensors)


def roving_channels(model, accelerometer: int = ACCELEROMETER):
    """(responses, references): the accelerometer under each hit point h1..h6."""
    first = model.excitation_names.index("h1")
    n = model.n_sensors
    return np.full(n, accelerometer), np.arange(first, first + n)


def one_dataset(k: int, sigma: float, seed: int, model=None) -> dict:
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.inference.intervals import parameter_intervals

    model = model or roving_model()
    channels = roving_channels(model)
    rng = np.random.default_rng([seed, k])
    truth = rng.uniform(-TRUTH_RANGE, TRUTH_RANGE, model.n_segments)
    Z = model.frf_channels(truth, freqs, *channels, method="direct")
    u = np.abs(Z) * (1.0 + sigma * rng.standard_normal(Z.shape))
    start = truth + rng.uniform(-START_OFFSET, START_OFFSET, truth.size)
    t0 = time.perf_counter()
    refined = parameter_intervals(model, freqs, u, start, LOWER, UPPER, channels=channels, max_jacobians=4)
    iv = refined.intervals
    return {"dataset": k, "truth": truth, "estimate": iv.estimate, "low": iv.low, "high": iv.high,
            "covered": iv.contains(truth), "at_optimum": refined.at_optimum, "jacobians": refined.jacobians,
            "seconds": time.perf_counter() - t0, "noise_sigma": iv.noise_sigma}


def coverage(n: int, sigma: float, seed: int) -> dict:
    model = roving_model()
    rows = [one_dataset(k, sigma, seed, model) for k in range(n)]
    covered = np.array([r["covered"] for r in rows])
    return {"n_sets": n, "covered": int(covered.sum()), "of": int(covered.size), "rate": float(covered.mean()),
            "per_parameter": covered.mean(axis=0).round(3).tolist(),
            "all_at_optimum": bool(all(r["at_optimum"] for r in rows)),
            "median_seconds": float(np.median([r["seconds"] for r in rows])),
            "median_jacobians": float(np.median([r["jacobians"] for r in rows]))}


def cost_per_reference(repeat: int = 3) -> dict:
    """Seconds of one exact Jacobian with its FRF, for 1, 2, 3 and 6 references (one response each)."""
    from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as freqs
    from fe_core.solvers.sensitivity import log_amplitude_jacobian

    model = roving_model()
    responses, references = roving_channels(model)
    out = {}
    for k in (1, 2, 3, 6):
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            log_amplitude_jacobian(model, ALPHA_ACTUAL, freqs, channels=(responses[:k], references[:k]))
            times.append(time.perf_counter() - t0)
        out[k] = float(np.median(times))
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        model.frf(ALPHA_ACTUAL, freqs)
        times.append(time.perf_counter() - t0)
    out["fe_run"] = float(np.median(times))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.roving_coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=20)
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--seed", type=int, default=30)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--no-cost", action="store_true")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    result = coverage(args.n, args.noise, args.seed)
    print(f"roving hammer (1 accelerometer, 6 hit points), {args.n} data sets, {args.noise:.1%} noise: "
          f"{result['covered']} of {result['of']} intervals cover the truth ({result['rate']:.3f}); per parameter "
          f"{result['per_parameter']}; all at the optimum: {result['all_at_optimum']}; median "
          f"{result['median_jacobians']:g} Jacobians, {result['median_seconds']:.1f} s per data set")
    if not args.no_cost:
        cost = cost_per_reference(args.repeat)
        fe = cost.pop("fe_run")
        print("one exact Jacobian with its FRF: " + ", ".join(f"{k} reference(s) {v:.2f} s" for k, v in cost.items())
              + f"; one FE run (Krylov FRF, 6 sensors, 1 load) {fe:.2f} s")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
