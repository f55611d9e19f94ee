"""Property tests: whatever a measured-data file holds, the reader returns valid data or a MeasuredDataError.

No other exception type (a ``KeyError`` from deep inside pyarrow or pyuff, an
``IndexError``...) may escape: the command line turns MeasuredDataError into
exit code 2 with the file named, anything else would be a traceback.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tasks.io.measured import MeasuredDataError, read_measured

REPO = Path(__file__).resolve().parents[2]
BENCHMARK = REPO / "data" / "benchmark"
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _read_or_refuse(path: Path):
    """Read; a refusal must name the file. A success must satisfy the format's invariants."""
    try:
        m = read_measured(path)
    except MeasuredDataError as exc:
        assert str(exc).startswith(f"{path}: ")
        return None
    assert np.all(np.diff(m.frequencies_hz) > 0) and np.all(m.frequencies_hz > 0)
    assert np.all(np.isfinite(m.amplitude)) and np.all(m.amplitude > 0)
    assert m.amplitude.shape == (m.frequencies_hz.size, m.sensors.size)
    return m


@FUZZ
@given(data=st.binary(min_size=1, max_size=2000), suffix=st.sampled_from([".csv", ".parquet", ".uff"]))
def test_arbitrary_bytes_are_read_or_refused(tmp_path, data, suffix):
    path = tmp_path / f"m{suffix}"
    path.write_bytes(data)
    _read_or_refuse(path)


@FUZZ
@given(name=st.sampled_from(["measured.csv", "measured.parquet", "measured.uff"]), data=st.data())
def test_a_benchmark_file_cut_anywhere_is_read_or_refused(tmp_path, name, data):
    raw = (BENCHMARK / name).read_bytes()
    cut = data.draw(st.integers(1, len(raw) - 1))
    path = tmp_path / name
    path.write_bytes(raw[:cut])
    m = _read_or_refuse(path)
    if m is not None:
        # A CSV cut at a line end, or a UFF cut between datasets or in its last delimiter, is a complete
        # grid of what is left (the flow's preflight refuses missing sensors): never wrong numbers.
        assert not name.endswith(".parquet")
        full = read_measured(BENCHMARK / name)
        rows = np.searchsorted(full.frequencies_hz, m.frequencies_hz)
        cols = np.searchsorted(full.sensors, m.sensors)
        np.testing.assert_array_equal(full.frequencies_hz[rows], m.frequencies_hz)
        np.testing.assert_array_equal(full.sensors[cols], m.sensors)
        np.testing.assert_allclose(m.amplitude, full.amplitude[np.ix_(rows, cols)], rtol=1e-6)


@FUZZ
@given(data=st.data())
def test_a_benchmark_csv_with_one_byte_changed_is_read_or_refused(tmp_path, data):
    raw = bytearray((BENCHMARK / "measured.csv").read_bytes())
    i = data.draw(st.integers(0, len(raw) - 1))
    raw[i] = data.draw(st.integers(0, 255))
    path = tmp_path / "m.csv"
    path.write_bytes(bytes(raw))
    _read_or_refuse(path)


@FUZZ
@given(cells=st.lists(st.lists(st.text(max_size=8), min_size=1, max_size=6), min_size=1, max_size=8),
       header=st.sampled_from(["sensor,frequency_hz,amplitude", "sensor,frequency_hz,amplitude,real,imag"]))
def test_random_cells_under_a_valid_header_are_read_or_refused(tmp_path, cells, header):
    path = tmp_path / "m.csv"
    path.write_text(header + "\n" + "\n".join(",".join(row) for row in cells) + "\n", encoding="utf-8",
                    errors="surrogatepass")
    _read_or_refuse(path)
