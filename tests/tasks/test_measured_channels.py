"""Tests for response/reference channels, FRF kinds, coherence and UFF58 with reference nodes.

References are independent of the readers: tables are written by hand here,
UFF files by pyuff's own ``prepare_58`` (as a test system's export would be),
and kind conversions are computed here from ``w = 2 pi f``.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import pyuff

from tasks.io.measured import (UFF_ORDINATE_RTOL, MeasuredDataError, MeasuredFRF, parse_dof, read_measured,
                               write_measured)

#: Conversions multiply by (j w)^-k once: a few ulps.
CONVERT_RTOL = 1e-14


def _receptance(rng, p, n):
    modulus = 10.0 ** rng.uniform(-8, -5, size=(p, n))
    return modulus * np.exp(1j * rng.uniform(-np.pi, np.pi, size=(p, n)))


@pytest.fixture
def rng():
    return np.random.default_rng(16)


def _write_rows(path, header, rows, comments=()):
    text = "".join(f"{c}\n" for c in comments) + header + "\n"
    text += "".join(",".join(repr(float(v)) if isinstance(v, float) else str(v) for v in row) + "\n" for row in rows)
    path.write_text(text)
    return path


# --- kinds --------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, power", [("accelerance", 2), ("mobility", 1), ("receptance", 0)])
def test_complex_kinds_convert_to_receptance(tmp_path, rng, kind, power):
    f = np.array([10.0, 55.5, 390.25])
    d = _receptance(rng, f.size, 2)
    h = d * (2j * np.pi * f[:, None]) ** power  # the file's kind, from the receptance
    rows = [(name, "hammer", fi, h[i, j].real, h[i, j].imag, kind)
            for i, fi in enumerate(f.tolist()) for j, name in enumerate(["s1", "s2"])]
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,reference,frequency_hz,real,imag,kind", rows))
    np.testing.assert_allclose(m.complex_frf, d, rtol=CONVERT_RTOL, atol=0)
    np.testing.assert_allclose(m.amplitude, np.abs(d), rtol=CONVERT_RTOL, atol=0)
    assert m.responses == ("s1", "s2") and m.references == ("hammer", "hammer")
    assert (m.kinds is None) == (kind == "receptance")
    assert any(f"from {kind} to receptance" in note for note in m.notes) == (kind != "receptance")


def test_amplitude_only_mobility_divides_by_omega(tmp_path):
    rows = [("s1", 100.0, 2.0), ("s1", 200.0, 3.0)]  # (m/s)/N
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,frequency_hz,amplitude", rows,
                                  comments=["# kind = mobility"]))
    np.testing.assert_allclose(m.amplitude[:, 0], [2.0 / (2 * np.pi * 100), 3.0 / (2 * np.pi * 200)],
                               rtol=CONVERT_RTOL)
    assert m.complex_frf is None and m.references == (None,)


def test_kind_column_per_row_mixes_kinds_per_channel(tmp_path):
    rows = [("s1", 50.0, 1.0, "accelerance"), ("s2", 50.0, 1.0, "m/s/N"), ("s3", 50.0, 1.0, "m/N")]
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,frequency_hz,amplitude,kind", rows))
    w = 2 * np.pi * 50.0
    np.testing.assert_allclose(m.amplitude[0], [1 / w**2, 1 / w, 1.0], rtol=CONVERT_RTOL)
    assert m.kinds == ("accelerance", "mobility", "receptance")


def test_parquet_metadata_declares_the_files_kind(tmp_path):
    table = pa.table({"response": ["s1"], "frequency_hz": [10.0], "amplitude": [4.0]})
    table = table.replace_schema_metadata({"kind": "accelerance"})
    path = tmp_path / "m.parquet"
    pq.write_table(table, path)
    assert read_measured(path).amplitude[0, 0] == pytest.approx(4.0 / (2 * np.pi * 10.0) ** 2, rel=CONVERT_RTOL)


def test_zero_hz_line_of_an_accelerance_is_dropped_and_noted(tmp_path):
    rows = [("s1", 0.0, 0.0, 0.0), ("s1", 0.25, 1e-3, 2e-3), ("s1", 0.5, 3e-3, 1e-3)]
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,frequency_hz,real,imag", rows,
                                  comments=["# kind: accelerance"]))
    np.testing.assert_array_equal(m.frequencies_hz, [0.25, 0.5])
    assert any("dropped the 0 Hz line of 1 channel(s)" in note for note in m.notes)
    assert m.line_places == ("line 4", "line 5")  # comment, header, then the dropped 0 Hz row


# --- labels and channels ------------------------------------------------------------------------


@pytest.mark.parametrize("label, expected", [("101:+z", (101, 3)), ("101:z", (101, 3)), ("7:-X", (7, -1)),
                                             ("3:2", (3, 2)), ("3:-rz", (3, -6)), ("s1", None)])
def test_parse_dof(label, expected):
    assert parse_dof(label) == expected


def test_node_direction_labels_are_one_dof_whatever_their_spelling(tmp_path):
    rows = [("3:z", "1:+Z", 10.0, 1e-6), ("3:+3", "1:3", 10.0, 2e-6)]
    path = _write_rows(tmp_path / "m.csv", "response,reference,frequency_hz,amplitude", rows)
    with pytest.raises(MeasuredDataError, match="line 2 and line 3 both give response '3:\\+z', reference "
                                                "'1:\\+z' at frequency_hz 10.0"):
        read_measured(path)


def test_several_references_are_several_channels(tmp_path, rng):
    rows = []
    for f in (10.0, 20.0):
        for ref in ("1:+z", "2:+z"):
            for resp in ("1:+z", "2:+z", "3:+z"):
                rows.append((resp, ref, f, float(rng.uniform(1e-7, 1e-6))))
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,reference,frequency_hz,amplitude", rows))
    assert m.n_channels == 6
    assert list(zip(m.responses, m.references))[:4] == [("1:+z", "1:+z"), ("2:+z", "1:+z"), ("3:+z", "1:+z"),
                                                        ("1:+z", "2:+z")]
    np.testing.assert_array_equal(m.amplitude.ravel(), [row[3] for row in rows])


def test_coherence_is_carried(tmp_path):
    rows = [("s1", 10.0, 1e-6, 0.5), ("s1", 20.0, 2e-6, 1.0)]
    m = read_measured(_write_rows(tmp_path / "m.csv", "response,frequency_hz,amplitude,coherence", rows))
    np.testing.assert_array_equal(m.coherence[:, 0], [0.5, 1.0])


# --- refusals -----------------------------------------------------------------------------------

HEAD = "response,reference,frequency_hz,amplitude"


@pytest.mark.parametrize("content, expected", [
    (HEAD + ",coherence\ns1,h,10.0,1e-6,1.2\n", ["line 2", "coherence 1.2 is outside [0, 1]"]),
    (HEAD + ",coherence\ns1,h,10.0,1e-6,0.9\ns2,h,10.0,1e-6,-0.1\n", ["line 3", "coherence -0.1"]),
    (HEAD + "\ns1,h,10.0,1e-6\ns2,h,10.0,1e-6\ns1,h,10.0,2e-6\n",
     ["line 2 and line 4 both give response 's1', reference 'h' at frequency_hz 10.0"]),
    ("# kind = accelerance\n" + HEAD + "\ns1,h,10.0,1e-6\n# kind = mobility\ns1,h,20.0,1e-6\n",
     ["line 4 declares mobility", "line 1 declared accelerance", "mixed FRF kinds", "'kind' column"]),
    (HEAD + "\ns1,h,10.0,1e-6\n# kind = mobility\ns1,h,20.0,1e-6\n",
     ["line 3 declares mobility after data rows", "'kind' column"]),
    ("# kind = accelerance\n" + HEAD + ",kind\ns1,h,10.0,1e-6,mobility\n",
     ["line 3: kind mobility, but line 1 declares accelerance"]),
    (HEAD + ",kind\ns1,h,10.0,1e-6,velocity\ns1,h,20.0,1e-6,accelerance\n",
     ["line 2 and line 3", "given as mobility and as accelerance"]),
    (HEAD + ",kind\ns1,h,10.0,1e-6,jerk\n", ["line 2", "kind 'jerk'"]),
    (HEAD + "\ns1,h,0.0,1e-6\n", ["line 2", "frequency_hz 0.0 is not > 0"]),
    (HEAD + "\n3:w,h,10.0,1e-6\n", ["line 2", "response '3:w'", "unknown direction"]),
    (HEAD + "\n,h,10.0,1e-6\n", ["line 2", "response is empty"]),
    ("sensor,response,frequency_hz,amplitude\n1,s1,10.0,1e-6\n", ["both of the columns 'sensor'"]),
    ("sensor,reference,frequency_hz,amplitude\n1,h,10.0,1e-6\n", ["'reference' needs 'response'"]),
    (HEAD + "\ns1,h,10.0,1e-6\ns2,h,10.0,1e-6\ns1,h,20.0,1e-6\n",
     ["incomplete grid", "response 's2', reference 'h' has no row at frequency_hz 20.0"]),
], ids=["coherence above 1", "coherence below 0", "duplicated row", "two declared kinds", "declaration after data",
        "kind column against the declaration", "channel of two kinds", "unknown kind", "receptance at 0 Hz",
        "bad direction", "empty response", "sensor and response", "reference with sensor", "incomplete grid"])
def test_bad_channel_tables_name_file_and_line(tmp_path, content, expected):
    path = tmp_path / "m.csv"
    path.write_text(content)
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for text in expected:
        assert text in message, message


# --- writing: round trips in every kind -----------------------------------------------------------


def _labelled(rng, complex_data=True, coherence=True):
    f = np.arange(1, 41) * 0.25
    d = _receptance(rng, f.size, 3)
    return MeasuredFRF(f, np.arange(1, 4), np.abs(d), d if complex_data else None, "test",
                       responses=("1:+z", "2:+z", "1:+z"), references=("1:+z", "1:+z", "2:-y"),
                       coherence=rng.uniform(0.5, 1.0, size=d.shape) if coherence else None)


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".uff"])
@pytest.mark.parametrize("kind", ["receptance", "mobility", "accelerance"])
def test_write_in_any_kind_reads_back_the_same_receptance(tmp_path, rng, suffix, kind):
    m = _labelled(rng)
    back = read_measured(write_measured(tmp_path / f"m{suffix}", m, kind=kind))
    rtol = UFF_ORDINATE_RTOL if suffix == ".uff" else 4 * CONVERT_RTOL
    np.testing.assert_array_equal(back.frequencies_hz, m.frequencies_hz)  # even spacing: exact in UFF too
    np.testing.assert_allclose(back.complex_frf, m.complex_frf, rtol=rtol, atol=0)
    np.testing.assert_allclose(back.coherence, m.coherence, rtol=UFF_ORDINATE_RTOL, atol=0)
    assert back.responses == m.responses and back.references == m.references
    assert back.kinds == (None if kind == "receptance" else (kind,) * 3)


def test_uff_writer_refuses_names(tmp_path, rng):
    m = MeasuredFRF(np.array([1.0, 2.0]), [1], np.ones((2, 1)), None, "t", responses=("s1",), references=(None,))
    with pytest.raises(ValueError, match="NODE:DIR"):
        write_measured(tmp_path / "m.uff", m)
    assert list(tmp_path.iterdir()) == []


# --- UFF58 as a test system writes it -------------------------------------------------------------


def _frf58(rsp, ref, x, data, ordinate=12, func_type=4, spacing=1, denominator=13):
    return pyuff.prepare_58(
        binary=0, func_type=func_type, load_case_id=0, rsp_node=rsp[0], rsp_dir=rsp[1], ref_node=ref[0],
        ref_dir=ref[1], abscissa_spacing=spacing, abscissa_spec_data_type=18, ordinate_spec_data_type=ordinate,
        orddenom_spec_data_type=denominator, data=np.asarray(data), x=np.asarray(x, dtype=float))


def test_uff_mimo_accelerance_with_coherence(tmp_path, rng):
    x = np.arange(0, 9) * 0.5  # 0 Hz included, as a test system exports it
    pairs = [((11, 3), (11, 3)), ((12, -3), (11, 3)), ((11, 3), (12, 1))]
    d = _receptance(rng, x.size, len(pairs))
    a = d * -(2 * np.pi * x[:, None]) ** 2
    a[0] = 1e-9 + 1e-9j  # noise at 0 Hz
    coherence = rng.uniform(0, 1, size=a.shape)
    sets = []
    for j, (rsp, ref) in enumerate(pairs):
        sets.append(_frf58(rsp, ref, x, a[:, j]))
        sets.append(_frf58(rsp, ref, x, coherence[:, j], ordinate=0, func_type=6, denominator=0))
    path = tmp_path / "test.uff"
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")
    m = read_measured(path)
    assert m.responses == ("11:+z", "12:-z", "11:+z") and m.references == ("11:+z", "11:+z", "12:+x")
    np.testing.assert_array_equal(m.frequencies_hz, x[1:])
    np.testing.assert_allclose(m.complex_frf, d[1:], rtol=UFF_ORDINATE_RTOL, atol=0)
    np.testing.assert_allclose(m.coherence, coherence[1:], rtol=UFF_ORDINATE_RTOL, atol=0)
    assert m.kinds == ("accelerance",) * 3
    assert m.places[1] == "dataset 3 (response 12:-z, reference 11:+z) point 1"
    assert any("0 Hz" in note for note in m.notes)


@pytest.mark.parametrize("build, expected", [
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3, ordinate=0)],
     ["dataset 1 (response 1:+z, reference 1:+z)", "ordinate specific data type 0"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3, denominator=12)],
     ["dataset 1", "denominator type 12"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3),
                _frf58((2, 3), (0, 3), x, np.ones(x.size) * 1e-3)],
     ["dataset 2", "with and without a reference node"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3),
                _frf58((1, 3), (1, 3), x, np.full(x.size, 0.9), ordinate=0, func_type=6),
                _frf58((2, 3), (1, 3), x, np.ones(x.size) * 1e-3)],
     ["dataset 3", "no coherence dataset"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3),
                _frf58((1, 3), (1, 3), x, np.full(x.size, 1.5), ordinate=0, func_type=6)],
     ["dataset 2 (coherence of response 1:+z, reference 1:+z) point 1", "coherence 1.5"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3),
                _frf58((5, 3), (1, 3), x, np.full(x.size, 0.9), ordinate=0, func_type=6)],
     ["dataset 2", "belongs to no FRF"]),
    (lambda x: [_frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3),
                _frf58((1, 3), (1, 3), x, np.ones(x.size) * 1e-3, ordinate=11)],
     ["dataset 1", "dataset 2", "both give response '1:+z', reference '1:+z'"]),
], ids=["unknown ordinate", "not over force", "mixed reference forms", "coherence for some", "coherence above 1",
        "coherence without FRF", "duplicated channel"])
def test_bad_uff_names_the_dataset(tmp_path, build, expected):
    path = tmp_path / "m.uff"
    pyuff.UFF(str(path)).write_sets(build(np.array([1.0, 2.0, 3.0])), mode="overwrite")
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for text in expected:
        assert text in message, message


def test_uff_in_other_units_is_converted_by_dataset_164(tmp_path):
    """Unlabelled data in the foot-pound system (164 gives file units per SI unit: 1/0.3048 ft per m,
    1/4.4482216152605 lbf per N): an accelerance of 1e-3 (ft/s^2)/lbf is 1e-3 x 0.3048 / 4.448... (m/s^2)/N."""
    path = tmp_path / "m.uff"
    uff = pyuff.UFF(str(path))
    uff.write_sets(pyuff.prepare_164(units_code=2, units_description="Foot-pound", temp_mode=1,
                                     length=1 / 0.3048, force=1 / 4.4482216152605, temp=1.8, temp_offset=459.67),
                   mode="overwrite")
    uff.write_sets(_frf58((1, 3), (1, 3), np.array([1.0, 2.0]), np.ones(2) * 1e-3), mode="add")
    m = read_measured(path)
    expected = 1e-3 * 0.3048 / 4.4482216152605 / (2 * np.pi * np.array([1.0, 2.0])) ** 2
    np.testing.assert_allclose(m.amplitude[:, 0], expected, rtol=1e-12)
    assert any("dataset 164" in note and "units code 2" in note for note in m.notes)
