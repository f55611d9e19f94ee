"""The update flow on many responses: the benchmark measured at 2 x 50 lines x 6 sensors = 600.

    python -m benchmarks.many_responses_flow [--lines 50] [--run-dir PATH]

"Measured" data: the FE model at the SPEC's actual alpha (direct solver, noise-free), at
``lines`` equally spaced frequencies over each of the benchmark's two measured windows
(106-116 Hz and 285-295 Hz, widened by 2 Hz each side). With ``outputs = "auto"`` the flow
must pick the reduced output basis (k > 200) and recover alpha. Prints the train stages'
choice, rank r and captured variance, the summary and the parameter errors.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from flows.config import UpdateConfig
from tasks.io.measured import MeasuredFRF, write_measured
from tasks.runstore import RunStore


def measured_frequencies(lines: int) -> np.ndarray:
    f = MEASUREMENT_FREQUENCIES_HZ
    low, high = f[f < 200], f[f >= 200]
    return np.concatenate([np.linspace(w.min() - 2, w.max() + 2, lines) for w in (low, high)])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lines", type=int, default=50, help="lines per window (default 50: k = 2 x 50 x 6 = 600)")
    p.add_argument("--run-dir", default=None, help="folder for the data and the run (default: a temporary one)")
    args = p.parse_args(argv)
    from flows.update import update_flow

    out = Path(args.run_dir or tempfile.mkdtemp(prefix="many-responses-flow-"))
    out.mkdir(parents=True, exist_ok=True)
    model = three_plate()
    freqs = measured_frequencies(args.lines)
    Z = model.frf(ALPHA_ACTUAL, freqs, method="direct")
    path = out / "measured.parquet"
    write_measured(path, MeasuredFRF(frequencies_hz=freqs, sensors=list(range(1, model.n_sensors + 1)),
                                     amplitude=abs(Z), complex_frf=Z, source="three_plate at ALPHA_ACTUAL"))
    config = UpdateConfig(run_id="auto", runs_dir=str(out / "runs"), measured=str(path), w=2000, n_jobs=2,
                          true_parameters=ALPHA_ACTUAL.tolist())
    t0 = time.perf_counter()
    summary = update_flow(config)
    wall = time.perf_counter() - t0
    store = RunStore(out / "runs" / "auto")
    k = Z.size
    print(f"k = {len(freqs)} lines x {model.n_sensors} sensors = {k} responses; outputs = {config.outputs!r}")
    for it in range(1, summary["iterations"] + 1):
        if store.is_finished(it, "train"):
            info = store.stage_info(it, "train")
            print(f"iteration {it}: n = {info['n_train']}, outputs = {info['outputs']}, "
                  f"r = {info.get('components')}, captured = {info.get('captured')}")
    est = np.array(list(summary["parameters"].values()))
    print(f"FE runs {summary['fe_evaluations']}, overall error {summary['overall_error']:.3e}, wall {wall:.0f} s")
    print("alpha found  ", np.round(est, 5).tolist())
    print("alpha actual ", ALPHA_ACTUAL.tolist())
    print(f"max |error| {np.max(np.abs(est - ALPHA_ACTUAL)):.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
