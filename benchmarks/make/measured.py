"""Write the benchmark measurement: the FE model at the SPEC's actual alpha, noise-free.

    python -m benchmarks.make.measured            # data/benchmark/measured.{csv,parquet,uff}

The FRF uses the direct solver (the reference), and the file keeps the complex
values as well as the amplitude.
"""

from __future__ import annotations

import sys
from pathlib import Path

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from tasks.io.measured import MeasuredFRF, write_measured

OUT = Path(__file__).resolve().parents[2] / "data" / "benchmark"


def main() -> int:
    model = three_plate()
    Z = model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, method="direct")
    measured = MeasuredFRF(
        frequencies_hz=MEASUREMENT_FREQUENCIES_HZ,
        sensors=list(range(1, model.n_sensors + 1)),
        amplitude=abs(Z),
        complex_frf=Z,
        source="fe_core.benchmark.three_plate at ALPHA_ACTUAL",
    )
    OUT.mkdir(parents=True, exist_ok=True)
    for suffix in (".csv", ".parquet", ".uff"):
        write_measured(OUT / f"measured{suffix}", measured)
        print(f"wrote {OUT / ('measured' + suffix)}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.measured", __doc__)
    sys.exit(main())
