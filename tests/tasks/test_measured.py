"""Tests for tasks.io.measured: the measured-FRF format, reader, writer, UFF58 and CLI.

References are independent of the module: tables are written by hand here
(``_csv_text``), and UFF files are checked by slicing their fixed-width text.
"""

import logging
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import pyuff
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tasks.io import measured as module
from tasks.io.measured import (
    AMPLITUDE_RTOL,
    UFF_FREQUENCY_RTOL,
    UFF_ORDINATE_RTOL,
    MeasuredDataError,
    MeasuredFRF,
    main,
    read_measured,
    write_measured,
)

REPO = Path(__file__).resolve().parents[2]
# The measurement bands, on a 0.25 Hz step that 6 digits represent exactly.
BAND_HZ = np.r_[np.arange(106.0, 116.01, 0.25), np.arange(285.0, 295.01, 0.25)]
HYPOTHESIS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


def _random_measured(rng, frequencies_hz, sensors, complex_data=True):
    shape = (len(frequencies_hz), len(sensors))
    modulus = 10.0 ** rng.uniform(-9, -4, size=shape)
    frf = modulus * np.exp(1j * rng.uniform(-np.pi, np.pi, size=shape))
    return MeasuredFRF(
        frequencies_hz=frequencies_hz,
        sensors=sensors,
        amplitude=np.abs(frf),
        complex_frf=frf if complex_data else None,
        source="test",
    )


def _rows(measured):
    """Long rows (sensor, frequency, amplitude[, real, imag]) as Python numbers."""
    rows = []
    for i, f in enumerate(measured.frequencies_hz.tolist()):
        for j, s in enumerate(measured.sensors.tolist()):
            row = [s, f, float(measured.amplitude[i, j])]
            if measured.complex_frf is not None:
                value = complex(measured.complex_frf[i, j])
                row += [value.real, value.imag]
            rows.append(row)
    return rows


def _csv_text(rows, complex_data):
    header = "sensor,frequency_hz,amplitude" + (",real,imag" if complex_data else "")
    # str of a Python float is its shortest exact repr; rows may also hold strings.
    return "".join(",".join(map(str, row)) + "\n" for row in [header.split(",")] + rows)


def _assert_same(actual, expected):
    np.testing.assert_array_equal(actual.frequencies_hz, expected.frequencies_hz)
    np.testing.assert_array_equal(actual.sensors, expected.sensors)
    np.testing.assert_array_equal(actual.amplitude, expected.amplitude)
    if expected.complex_frf is None:
        assert actual.complex_frf is None
    else:
        np.testing.assert_array_equal(actual.complex_frf, expected.complex_frf)


@st.composite
def measured_grids(draw, min_size=1):
    sensors = sorted(draw(st.sets(st.integers(1, 40), min_size=min_size, max_size=4)))
    frequencies = sorted(
        draw(st.sets(st.floats(1e-3, 1e4, allow_nan=False), min_size=min_size, max_size=6))
    )
    shape = (len(frequencies), len(sensors))
    size = shape[0] * shape[1]
    modulus = draw(st.lists(st.floats(1e-12, 1e-2), min_size=size, max_size=size))
    phase = draw(st.lists(st.floats(-np.pi, np.pi), min_size=size, max_size=size))
    frf = np.reshape(modulus, shape) * np.exp(1j * np.reshape(phase, shape))
    complex_data = draw(st.booleans())
    return MeasuredFRF(
        np.array(frequencies), np.array(sensors), np.abs(frf), frf if complex_data else None
    )


# --- reading a hand-written table -------------------------------------------------------------


def test_rows_in_any_order_give_sorted_grid(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(
        "sensor,frequency_hz,amplitude\n"
        "2,290.5,4e-6\n"
        "1,106.0,1e-6\n"
        "1,290.5,3e-6\n"
        "2,106.0,2e-6\n"
    )
    measured = read_measured(path)
    np.testing.assert_array_equal(measured.frequencies_hz, [106.0, 290.5])
    np.testing.assert_array_equal(measured.sensors, [1, 2])
    np.testing.assert_array_equal(measured.amplitude, [[1e-6, 2e-6], [3e-6, 4e-6]])
    assert measured.complex_frf is None
    assert measured.source == str(path)


def test_complex_columns_give_complex_frf(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("sensor,frequency_hz,amplitude,real,imag\n1,106.0,5e-6,3e-6,-4e-6\n")
    measured = read_measured(path)
    assert measured.complex_frf[0, 0] == complex(3e-6, -4e-6)


def test_amplitude_within_rtol_of_modulus_is_accepted(tmp_path):
    path = tmp_path / "m.csv"
    amplitude = 5e-6 * (1 + 0.5 * AMPLITUDE_RTOL)
    path.write_text(f"sensor,frequency_hz,amplitude,real,imag\n1,106.0,{amplitude!r},3e-6,4e-6\n")
    assert read_measured(path).amplitude[0, 0] == amplitude


def test_blank_lines_are_skipped_but_counted(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("sensor,frequency_hz,amplitude\n1,106.0,1e-6\n\n2,106.0,2e-6\n\n")
    np.testing.assert_array_equal(read_measured(path).sensors, [1, 2])
    path.write_text("sensor,frequency_hz,amplitude\n1,106.0,1e-6\n\n2,106.0,nan\n")
    with pytest.raises(MeasuredDataError, match=r"\bline 4\b"):
        read_measured(path)


def test_byte_order_mark_before_header_is_accepted(tmp_path):
    path = tmp_path / "m.csv"
    path.write_bytes("\ufeffsensor,frequency_hz,amplitude\n1,106.0,1e-6\n".encode("utf-8"))
    assert read_measured(path).amplitude[0, 0] == 1e-6


# --- bad inputs ---------------------------------------------------------------------------------

HEADER = "sensor,frequency_hz,amplitude\n"
COMPLEX_HEADER = "sensor,frequency_hz,amplitude,real,imag\n"
GOOD_ROWS = ["1,106.0,1e-6", "2,106.0,2e-6", "1,107.0,3e-6", "2,107.0,4e-6"]  # lines 2-5


def _table(*replace, header=HEADER, rows=GOOD_ROWS):
    """GOOD_ROWS with (line number, text) replacements; text None drops the line."""
    lines = dict(enumerate(rows, start=2))
    lines.update(replace)
    return header + "".join(f"{text}\n" for text in lines.values() if text is not None)


BAD_INPUTS = [
    # (case, file name, content, substrings the message must contain besides the path)
    ("missing column", "m.csv", "sensor,frequency_hz\n1,106.0\n", ["missing", "'amplitude'"]),
    (
        "unknown column",
        "m.csv",
        "sensor,frequency_hz,amplitude,phase\n1,106.0,1e-6,0.5\n",
        ["'phase'", "allowed columns: sensor, frequency_hz, amplitude, real, imag"],
    ),
    ("real without imag", "m.csv", "sensor,frequency_hz,amplitude,real\n1,106,1e-6,1e-6\n", ["'imag'"]),
    ("repeated column", "m.csv", "sensor,amplitude,frequency_hz,amplitude\n", ["'amplitude'", "more than once"]),
    ("duplicated row", "m.csv", _table((5, "1,106.0,5e-6")), ["line 2 and line 5", "sensor 1", "106.0"]),
    ("nan amplitude", "m.csv", _table((3, "2,106.0,nan")), ["line 3", "amplitude"]),
    ("infinite frequency", "m.csv", _table((4, "1,inf,3e-6")), ["line 4", "frequency_hz"]),
    ("negative amplitude", "m.csv", _table((5, "2,107.0,-4e-6")), ["line 5", "amplitude", "> 0"]),
    ("zero amplitude", "m.csv", _table((2, "1,106.0,0")), ["line 2", "amplitude", "> 0"]),
    ("zero frequency", "m.csv", _table((3, "2,0.0,2e-6")), ["line 3", "frequency_hz", "> 0"]),
    ("fractional sensor", "m.csv", _table((4, "1.5,107.0,3e-6")), ["line 4", "sensor", "integer"]),
    ("sensor zero", "m.csv", _table((2, "0,106.0,1e-6")), ["line 2", "sensor", ">= 1"]),
    ("text in a number", "m.csv", _table((4, "1,107.0,abc")), ["line 4", "amplitude", "'abc'"]),
    ("empty cell", "m.csv", _table((3, "2,,2e-6")), ["line 3", "frequency_hz", "empty"]),
    ("extra field", "m.csv", _table((4, "1,107.0,3e-6,9")), ["line 4", "4 fields"]),
    ("grid incomplete", "m.csv", _table((5, None)), ["incomplete grid", "sensor 2", "107.0"]),
    (
        "amplitude is not the modulus",
        "m.csv",
        COMPLEX_HEADER + "1,106.0,5e-6,3e-6,4e-6\n2,106.0,5.1e-6,3e-6,4e-6\n",
        ["line 3", "hypot(real, imag)"],
    ),
    ("empty file", "m.csv", "", ["empty file"]),
    ("header only", "m.csv", HEADER, ["no data rows"]),
    ("binary garbage csv", "m.csv", b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe", ["not a CSV"]),
    ("text with NUL bytes", "m.csv", "sensor\x00,frequency_hz,amplitude\n1,2,3\n", ["not a CSV"]),
    ("binary garbage parquet", "m.parquet", b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe", ["not a Parquet"]),
    ("text parquet", "m.parquet", _table(), ["not a Parquet"]),
    ("garbage uff", "m.uff", b"\x00\x01 hello\n", ["no FRF"]),
    ("wrong extension", "m.txt", _table(), ["'.txt'", ".csv, .parquet, .uff, .unv"]),
]


@pytest.mark.parametrize(
    "name, content, expected",
    [case[1:] for case in BAD_INPUTS],
    ids=[case[0] for case in BAD_INPUTS],
)
def test_bad_input_raises_naming_file_and_place(tmp_path, name, content, expected):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert "np." not in message  # numbers as the user wrote them, not numpy reprs
    for text in expected:
        assert text in message


@pytest.mark.parametrize(
    "columns, expected",
    [
        ({"sensor": [1, 2], "frequency_hz": [106.0, 106.0], "amplitude": [1e-6, np.nan]}, "row 2"),
        ({"sensor": [1, None], "frequency_hz": [106.0, 106.0], "amplitude": [1e-6, 2e-6]}, "row 2"),
        ({"sensor": [1, 2], "frequency_hz": ["106", "x"], "amplitude": [1e-6, 2e-6]}, "row 2"),
        ({"sensor": [1, 2], "frequency_hz": [106.0, 106.0], "amp": [1e-6, 2e-6]}, "'amp'"),
    ],
    ids=["nan", "null", "text", "unknown column"],
)
def test_bad_parquet_names_file_and_row(tmp_path, columns, expected):
    path = tmp_path / "m.parquet"
    pq.write_table(pa.table(columns), path)
    with pytest.raises(MeasuredDataError, match=re.escape(f"{path}: ")) as info:
        read_measured(path)
    assert expected in str(info.value)


def test_missing_file_raises_oserror(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_measured(tmp_path / "absent.csv")


# --- expected sensors and frequencies ----------------------------------------------------------


def test_expected_sensors_name_missing_and_extra(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(_table())
    assert read_measured(path, expected_sensors=[2, 1]).sensors.tolist() == [1, 2]
    with pytest.raises(MeasuredDataError, match=r"missing \[3\], unexpected \[2\]"):
        read_measured(path, expected_sensors=[1, 3])


def test_expected_frequencies_match_within_rtol(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(_table())
    rtol = 1e-9
    inside = [106.0 * (1 + 0.5 * rtol), 107.0]
    np.testing.assert_array_equal(
        read_measured(path, expected_frequencies_hz=inside).frequencies_hz, [106.0, 107.0]
    )
    outside = [106.0 * (1 + 2 * rtol), 107.0, 108.0]
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path, expected_frequencies_hz=outside, frequency_rtol=rtol)
    message = str(info.value)
    assert f"missing [{outside[0]!r}, 108.0] Hz" in message
    assert "unexpected [106.0] Hz" in message


# --- properties ---------------------------------------------------------------------------------


@HYPOTHESIS
@given(measured=measured_grids(), suffix=st.sampled_from([".csv", ".parquet"]))
def test_write_then_read_gives_same_arrays(tmp_path, measured, suffix):
    path = write_measured(tmp_path / f"m{suffix}", measured)
    _assert_same(read_measured(path), measured)


@HYPOTHESIS
@given(measured=measured_grids(), data=st.data())
def test_row_permutation_reads_the_same(tmp_path, measured, data):
    rows = data.draw(st.permutations(_rows(measured)))
    path = tmp_path / "m.csv"
    path.write_text(_csv_text(rows, measured.complex_frf is not None))
    _assert_same(read_measured(path), measured)


@HYPOTHESIS
@given(
    measured=measured_grids(min_size=2),
    kind=st.sampled_from(["nan", "inf", "negative", "duplicate", "drop"]),
    data=st.data(),
)
def test_single_corruption_names_its_row(tmp_path, measured, kind, data):
    # min_size=2: dropping a row of a 1-sensor or 1-frequency grid leaves a smaller
    # complete grid, which only expected_sensors / expected_frequencies_hz can catch.
    rows = [[repr(value) for value in row] for row in _rows(measured)]
    i = data.draw(st.integers(0, len(rows) - 1))
    line = i + 2  # header is line 1
    n_columns = 3 if kind == "negative" else len(rows[i])  # real/imag may be negative
    column = data.draw(st.integers(0, n_columns - 1))
    if kind == "nan":
        rows[i][column] = "nan"
    elif kind == "inf":
        rows[i][column] = "-inf"
    elif kind == "negative":
        rows[i][column] = "-" + rows[i][column]
    elif kind == "duplicate":
        rows.append(list(rows[i]))
    else:
        sensor, frequency = rows.pop(i)[:2]
    path = tmp_path / "m.csv"
    path.write_text(_csv_text(rows, measured.complex_frf is not None))
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    if kind == "duplicate":
        assert f"line {line} and line {len(rows) + 1} " in message
    elif kind == "drop":
        assert f"sensor {sensor} has no row at frequency_hz {frequency}" in message
    else:
        assert re.search(rf"\bline {line}\b", message)


# --- the dataclass ------------------------------------------------------------------------------


def test_measured_frf_arrays_are_read_only_copies(rng):
    frequencies = np.array([106.0, 107.0])
    measured = _random_measured(rng, frequencies, [1, 2])
    frequencies[0] = 1.0
    assert measured.frequencies_hz[0] == 106.0
    with pytest.raises(ValueError):
        measured.amplitude[0, 0] = 1.0
    with pytest.raises(AttributeError):
        measured.source = "other"


@pytest.mark.parametrize(
    "frequencies, sensors, amplitude",
    [
        ([107.0, 106.0], [1], [[1e-6], [1e-6]]),  # not increasing
        ([106.0, 107.0], [1, 1], np.full((2, 2), 1e-6)),  # repeated sensor
        ([106.0, 107.0], [1.5], [[1e-6], [1e-6]]),  # fractional sensor
        ([106.0, 107.0], [1], [[1e-6, 1e-6]]),  # shape (n, p) instead of (p, n)
        ([106.0], [1], [[-1e-6]]),  # negative amplitude
    ],
    ids=["unsorted", "repeated sensor", "fractional sensor", "transposed", "negative"],
)
def test_measured_frf_rejects_inconsistent_arrays(frequencies, sensors, amplitude):
    with pytest.raises(ValueError):
        MeasuredFRF(np.array(frequencies), np.array(sensors), np.array(amplitude))


def test_measured_frf_rejects_amplitude_not_modulus():
    frf = np.array([[3e-6 + 4e-6j]])
    with pytest.raises(ValueError):
        MeasuredFRF(np.array([106.0]), np.array([1]), np.abs(frf) * (1 + 2 * AMPLITUDE_RTOL), frf)


# --- the writer ---------------------------------------------------------------------------------


@pytest.mark.parametrize("complex_data", [True, False])
def test_csv_header_is_canonical(tmp_path, rng, complex_data):
    measured = _random_measured(rng, BAND_HZ[:3], [3, 1], complex_data)
    path = write_measured(tmp_path / "m.csv", measured)
    header = path.read_text().splitlines()[0]
    assert header == "sensor,frequency_hz,amplitude" + (",real,imag" if complex_data else "")


def test_parquet_columns_are_canonical_and_typed(tmp_path, rng):
    path = write_measured(tmp_path / "m.parquet", _random_measured(rng, BAND_HZ[:3], [1, 2]))
    schema = pq.read_schema(path)
    assert schema.names == ["sensor", "frequency_hz", "amplitude", "real", "imag"]
    assert schema.field("sensor").type == pa.int64()
    assert all(schema.field(name).type == pa.float64() for name in schema.names[1:])


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".uff"])
def test_write_goes_through_a_temporary_file_in_the_same_folder(tmp_path, rng, monkeypatch, suffix):
    moves = []

    def recording_replace(source, target):
        moves.append((Path(source), Path(target)))
        return real_replace(source, target)

    real_replace = module.os.replace
    monkeypatch.setattr(module.os, "replace", recording_replace)
    target = tmp_path / f"m{suffix}"
    target.write_text("old content")
    measured = _random_measured(rng, BAND_HZ[:4], [1, 2])
    write_measured(target, measured)
    assert len(moves) == 1 and moves[0][1] == target
    assert moves[0][0].parent == tmp_path and moves[0][0] != target
    assert sorted(tmp_path.iterdir()) == [target]
    assert read_measured(target).sensors.tolist() == [1, 2]


def test_failed_write_leaves_no_file(tmp_path, rng):
    single_frequency = _random_measured(rng, BAND_HZ[:1], [1])
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path / 'm.uff'}: UFF58 needs two")):
        write_measured(tmp_path / "m.uff", single_frequency)
    assert list(tmp_path.iterdir()) == []


def test_write_rejects_unsupported_extension(tmp_path, rng):
    with pytest.raises(MeasuredDataError, match="'.xlsx'"):
        write_measured(tmp_path / "m.xlsx", _random_measured(rng, BAND_HZ[:2], [1]))


# --- UFF dataset 58 -----------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".uff", ".unv"])
@pytest.mark.parametrize("complex_data", [True, False])
def test_uff_round_trip(tmp_path, rng, suffix, complex_data):
    measured = _random_measured(rng, BAND_HZ, [1, 2, 5], complex_data)
    back = read_measured(write_measured(tmp_path / f"m{suffix}", measured))
    np.testing.assert_array_equal(back.frequencies_hz, BAND_HZ)  # exact at 6 digits
    np.testing.assert_array_equal(back.sensors, [1, 2, 5])
    np.testing.assert_allclose(back.amplitude, measured.amplitude, rtol=UFF_ORDINATE_RTOL, atol=0)
    if complex_data:
        np.testing.assert_allclose(
            back.complex_frf, measured.complex_frf, rtol=UFF_ORDINATE_RTOL, atol=0
        )
    else:
        assert back.complex_frf is None


def test_uff_text_follows_dataset_58_layout(tmp_path, rng):
    measured = _random_measured(rng, BAND_HZ[[0, 1, -1]], [4, 7])
    lines = write_measured(tmp_path / "m.uff", measured).read_text().splitlines()
    # Per dataset: -1, 58, records 1-11, 3 data lines (one per frequency), -1.
    blocks = [lines[k : k + 17] for k in range(0, len(lines), 17)]
    assert len(blocks) == 2
    for j, block in enumerate(blocks):
        assert block[0] == "    -1" and block[1].strip() == "58" and block[-1] == "    -1"
        # Record 6, format 2(I5,I10),2(1X,10A1,I10,I4): function type, load case,
        # response node and direction, reference node and direction.
        spans = [(0, 5), (20, 30), (41, 51), (51, 55), (66, 76), (76, 80)]
        fields = [block[7][a:b].strip() for a, b in spans]
        assert fields == ["4", "1", str(measured.sensors[j]), "3", "0", "3"]
        # Record 7: ordinate type 6 (complex double), 3 points, spacing 0 (uneven).
        assert block[8].split()[:3] == ["6", "3", "0"]
        # Record 12, format E13.5,2E20.12: frequency, real, imaginary.
        values = np.array([[float(r[0:13]), float(r[13:33]), float(r[33:53])] for r in block[13:16]])
        np.testing.assert_array_equal(values[:, 0], measured.frequencies_hz)
        frf = values[:, 1] + 1j * values[:, 2]
        np.testing.assert_allclose(frf, measured.complex_frf[:, j], rtol=UFF_ORDINATE_RTOL, atol=0)


def test_uff_keeps_six_significant_digits_of_frequency(tmp_path, rng, caplog):
    frequencies = np.array([106.0625, 290.0])  # 106.0625 needs 7 digits
    measured = _random_measured(rng, frequencies, [1])
    with caplog.at_level(logging.WARNING, logger=module.__name__):
        path = write_measured(tmp_path / "m.uff", measured)
    assert "6 digits" in caplog.text
    back = read_measured(path).frequencies_hz
    assert back[0] != frequencies[0]
    np.testing.assert_allclose(back, frequencies, rtol=UFF_FREQUENCY_RTOL, atol=0)
    with pytest.raises(MeasuredDataError, match=r"missing \[106\.0625\]"):
        read_measured(path, expected_frequencies_hz=frequencies)
    read_measured(path, expected_frequencies_hz=frequencies, frequency_rtol=UFF_FREQUENCY_RTOL)


def test_uff_writer_refuses_frequencies_equal_at_six_digits(tmp_path, rng):
    measured = _random_measured(rng, np.array([106.0001, 106.0002]), [1])
    with pytest.raises(ValueError, match="distinct at 6 digits"):
        write_measured(tmp_path / "m.uff", measured)


def _dataset58(sensor, frequencies, data, func_type=4, rsp_dir=3):
    return pyuff.prepare_58(
        binary=0, func_type=func_type, rsp_node=sensor, rsp_dir=rsp_dir, ref_node=0, ref_dir=3,
        abscissa_spacing=0, abscissa_spec_data_type=18, ordinate_spec_data_type=8,
        orddenom_spec_data_type=13, data=np.asarray(data), x=np.asarray(frequencies, dtype=float),
    )


def test_uff_reader_skips_datasets_that_are_not_frfs(tmp_path):
    path = tmp_path / "m.uff"
    uff = pyuff.UFF(str(path))
    uff.write_sets(_dataset58(1, [106.0, 107.0], [0.9, 0.8], func_type=6), mode="overwrite")
    uff.write_sets(_dataset58(1, [106.0, 107.0], [1e-6 + 2e-6j, 3e-6 - 1e-6j]), mode="add")
    measured = read_measured(path)
    np.testing.assert_array_equal(measured.complex_frf, [[1e-6 + 2e-6j], [3e-6 - 1e-6j]])


@pytest.mark.parametrize(
    "datasets, expected",
    [
        ([(1, [106.0, 107.0], [1e-6, 2e-6], 4, 1)], ["dataset 1 (sensor 1)", "direction 1"]),
        ([(1, [106.0, 107.0], [1e-6, -2e-6], 4, 3)], ["dataset 1 (sensor 1) point 2", "> 0"]),
        (
            [(1, [106.0, 107.0], [1e-6, 2e-6], 4, 3), (2, [106.0, 108.0], [1e-6, 2e-6], 4, 3)],
            ["sensor 1 has no row at frequency_hz 108.0"],
        ),
        (
            [(1, [106.0, 107.0], [1e-6, 2e-6], 4, 3), (1, [106.0, 107.0], [1e-6, 2e-6], 4, 3)],
            ["dataset 1 (sensor 1) point 1 and dataset 2 (sensor 1) point 1"],
        ),
        (
            [(1, [106.0, 107.0], [1e-6, 2e-6], 4, 3), (2, [106.0, 107.0], [1e-6 + 0j, 2e-6j], 4, 3)],
            ["dataset 2 (sensor 2)", "mixed"],
        ),
        ([(1, [106.0, 107.0], [0.9, 0.9], 6, 3)], ["no FRF"]),
        ([(1, [106.0, 108.0, 107.0], [1e-6, 2e-6, 3e-6], 4, 3)], ["dataset 1 (sensor 1) point 3", "out of order"]),
    ],
    ids=["direction", "negative", "grid", "duplicate", "mixed", "coherence only", "frequencies out of order"],
)
def test_bad_uff_names_dataset(tmp_path, datasets, expected):
    path = tmp_path / "m.uff"
    sets = [_dataset58(s, f, d, func_type=t, rsp_dir=r) for s, f, d, t, r in datasets]
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    assert str(info.value).startswith(f"{path}: ")
    for text in expected:
        assert text in str(info.value)


# --- command line -------------------------------------------------------------------------------


def test_cli_prints_one_line_summary(tmp_path, rng, capsys):
    path = write_measured(tmp_path / "m.csv", _random_measured(rng, BAND_HZ, [1, 2, 3]))
    assert main([str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2  # the summary, then the one note: the unit (none declared: SI)
    assert f"3 sensors (1..3), {BAND_HZ.size} frequencies (106..295 Hz)" in out[0]
    assert "values read as SI (m/N)" in out[1]


def test_cli_prints_error_and_exits_2(tmp_path, capsys):
    path = tmp_path / "m.csv"
    path.write_text(_table((3, "2,106.0,-1")))
    assert main([str(path)]) == 2
    assert f"{path}: line 3" in capsys.readouterr().err


def test_cli_runs_as_module(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(_table((5, None)))
    result = subprocess.run(
        [sys.executable, "-m", "tasks.io.measured", str(path)],
        cwd=REPO, capture_output=True, text=True, check=False,
    )
    assert result.returncode == 2
    assert "sensor 2 has no row at frequency_hz 107.0" in result.stderr


def test_module_does_not_import_prefect():
    # Load the file alone, so that whatever tasks/__init__.py imports does not count.
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('measured', {module.__file__!r})\n"
        "spec.loader.exec_module(importlib.util.module_from_spec(spec))\n"
        "import pyuff, pyarrow.parquet\n"  # the lazy imports too
        "print(sorted(name for name in sys.modules if name.split('.')[0] == 'prefect'))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "[]"
