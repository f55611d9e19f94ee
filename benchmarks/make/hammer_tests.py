"""Two more simulated hammer tests of the benchmark: a roving hammer, and the hammer test exported as mobility.

    python -m benchmarks.make.hammer_tests      # data/examples/hammer_tests/, about two minutes

Both come from the same simulation as ``data/benchmark/hammer.uff`` (:func:`benchmarks.make.hammer.simulate`:
10 hits of +-30 % force per reference, 1 % response noise, a sensor floor of 1e-3 of each channel's largest
response, 0.2 % force noise; H1 and ordinary coherence at 1,601 lines, 0-400 Hz) of the SPEC's actual structure
(``fe_core.benchmark.ALPHA_ACTUAL``) solved with the direct sparse LU per line:

* ``roving.uff``: one accelerometer at test node 3 (+z, sensor s3) and the hammer at each of the six sensor
  points in turn (test nodes 1-6, +z): six references, each with its own 10 hits and seed. Its model file,
  ``model_roving.toml``, is the benchmark's with the six hit points as excitations ``h1`` .. ``h6``;
* ``mobility.uff``: ``data/benchmark/hammer.uff`` written again as mobility, velocity over force in (m/s)/N
  (the coherence and the averages as they were), what an analyser set to velocity exports.

Update them with ``python -m flows.update --model data/examples/hammer_tests/model_roving.toml --measured
data/examples/hammer_tests/roving.uff`` and ``python -m flows.update --measured
data/examples/hammer_tests/mobility.uff`` (docs/guide/measured-data.md).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "data" / "examples" / "hammer_tests"
SEED = 23
ACCELEROMETER = 3  # test node of the roving test's one response (sensor s3)


def roving_model_file() -> Path:
    """``model_roving.toml``: the benchmark's model file with its mesh path from here and the six hit points."""
    text = (REPO / "data" / "benchmark" / "model.toml").read_text()
    text = text.replace('mesh = "three_plate.inp"', 'mesh = "../../benchmark/three_plate.inp"')
    start = text.index('[[excitations]]\nname = "hammer"')  # its point is h5's: one excitation per test DOF
    end = text.index("\n\n", start) if "\n\n" in text[start:] else len(text)
    text = text[:start] + text[end + 2:]
    text = text.replace("# Written by python -m benchmarks.make.benchmark_model; the name three_plate is a shortcut to it.",
                        "# The benchmark's model file with a hammer at every sensor point (python -m "
                        "benchmarks.make.hammer_tests).")
    points = [[0.02875, 0.02, 0.01], [0.14375, 0.02, 0.01], [0.25075, 0.02, 0.01], [0.33375, 0.02, 0.01],
              [0.42475, 0.02, 0.01], [0.53975, 0.02, 0.01]]
    for j, point in enumerate(points, start=1):
        text += (f"\n[[excitations]]\nname = \"h{j}\"  # the roving hammer at sensor s{j}'s point along z\n"
                 f"point = {point}\ndirection = \"z\"\ntest_node = {j}\n")
    path = OUT / "model_roving.toml"
    path.write_text(text)
    return path


def main() -> int:
    from benchmarks.make.hammer import BAND_HZ, LINES, simulate, write_uff
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.io import read_model
    from tasks.io.measured import read_measured, write_measured

    t0 = time.perf_counter()
    OUT.mkdir(parents=True, exist_ok=True)
    model = read_model(roving_model_file())
    f = np.arange(LINES) * (BAND_HZ / (LINES - 1))
    response = model.sensor_test_dofs.index((ACCELEROMETER, 3))
    hits = [model.excitation_names.index(f"h{j}") for j in range(1, 7)]
    receptance = np.zeros((LINES, 6), complex)
    receptance[1:] = model.frf_channels(ALPHA_ACTUAL, f[1:], np.full(6, response), np.array(hits), method="direct")
    accelerance = -((2 * np.pi * f[:, None]) ** 2) * receptance
    H1, coherence = np.empty_like(accelerance), np.empty(accelerance.shape)
    for j in range(6):  # each hit point its own test of 10 hits
        H1[:, j:j + 1], coherence[:, j:j + 1] = simulate(accelerance[:, j:j + 1], f, np.random.default_rng([SEED, j]))
    write_uff(OUT / "roving.uff", f, H1, coherence, responses=[ACCELEROMETER] * 6, references=list(range(1, 7)))
    hammer = read_measured(REPO / "data" / "benchmark" / "hammer.uff")
    write_measured(OUT / "mobility.uff", hammer, kind="mobility")
    print(f"wrote {OUT.relative_to(REPO)}: roving.uff (accelerometer at {ACCELEROMETER}:+z, hammer at 1..6:+z), "
          f"model_roving.toml, mobility.uff (hammer.uff as (m/s)/N); {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.hammer_tests", __doc__)
    sys.exit(main())
