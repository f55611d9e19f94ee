"""Units of measured FRFs: UFF58 labels and dataset 164, CSV ``# unit`` and a ``unit`` column.

The SI reference is the benchmark's hammer test (``data/benchmark/hammer.uff``: the SPEC's actual
structure, solved with the direct solver, simulated impacts with 1 % noise), accelerance in (m/s^2)/N.
Each other file holds the same FRFs written as a test system would in another unit, the values scaled
with the unit's definition (g = 9.80665 m/s^2, in = 0.0254 m, lbf = 4.4482216152605 N). Read back, the
receptance must equal the SI file's to the UFF ordinate's 12 digits (``UFF_ORDINATE_RTOL``) plus the
rounding of one multiplication and, for mobility, one division by j w (a few 1e-16): 1e-10 relative.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import pyuff

from tasks.io.measured import MeasuredDataError, read_measured
from tasks.io.measured.units import frf_unit, numerator_unit

REPO = Path(__file__).resolve().parents[2]
HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
SAME_RTOL = 1e-10
G, INCH, LBF = 9.80665, 0.0254, 4.4482216152605


def _sets():
    return pyuff.UFF(str(HAMMER)).read_sets()


def write_variant(path: Path, unit: str, *, system=None, denominator="N", ordinate_type=None, label=None,
                  exponents=None) -> Path:
    """hammer.uff rewritten with its FRF values in ``unit`` ('g', 'mm/s^2', 'in/s^2', 'm/s', 'mm/s', 'in/s',
    'm', 'mm', 'in' over 'N'/'kN'/'lbf'); record 9's label ``label`` (default the unit), record 9's data type
    ``ordinate_type`` (default the unit's), dataset 164 ``system`` (dict, None = the file's SI one)."""
    quantity, length = numerator_unit(unit)
    power = {"acceleration": 0, "velocity": 1, "displacement": 2}[quantity]
    force = {"N": 1.0, "kN": 1e3, "lbf": LBF}[denominator]
    out = []
    for s in _sets():
        if s["type"] == 164 and system is not None:
            s.update(system)
        if s["type"] == 58 and power == 2:  # a receptance has no 0 Hz line to drop: start at the next one
            s.update(x=s["x"][1:], data=s["data"][1:], num_pts=s["num_pts"] - 1, abscissa_min=s["x"][1])
        if s["type"] == 58 and s["func_type"] == 4:
            x = s["x"]
            jw = 2j * np.pi * np.where(x > 0, x, 1.0)
            s["data"] = s["data"] / jw**power * force / length  # (m/s^2)/N -> unit/force
            s["ordinate_spec_data_type"] = ordinate_type or {"acceleration": 12, "velocity": 11,
                                                             "displacement": 8}[quantity]
            s["ordinate_axis_units_lab"] = unit if label is None else label
            s["orddenom_axis_units_lab"] = denominator
            if exponents:
                s.update(exponents)
        out.append(s)
    uff = pyuff.UFF(str(path))
    uff.write_sets(out, mode="overwrite", force_double=True)
    return path


@pytest.fixture(scope="module")
def reference():
    return read_measured(HAMMER)


def _assert_same(measured, reference):
    np.testing.assert_array_equal(measured.frequencies_hz, reference.frequencies_hz)
    gap = np.abs(measured.complex_frf - reference.complex_frf) / np.abs(reference.complex_frf)
    assert gap.max() <= SAME_RTOL


@pytest.mark.parametrize("unit, denominator, factor", [
    ("g", "N", G), ("mm/s^2", "N", 1e-3), ("in/s^2", "lbf", INCH / LBF), ("m/s", "N", 1.0), ("mm/s", "N", 1e-3),
    ("in/s", "kN", INCH / 1e3), ("m", "lbf", 1 / LBF), ("mm", "N", 1e-3), ("in", "N", INCH),
    ("m/s^2", "lbf", 1 / LBF),
])
def test_every_unit_reads_as_the_si_file(tmp_path, reference, unit, denominator, factor):
    measured = read_measured(write_variant(tmp_path / "v.uff", unit, denominator=denominator))
    _assert_same(measured, reference)
    assert set(measured.units) == {f"{unit}/{denominator}"}
    note = next(n for n in measured.notes if n.startswith(f"unit {unit}/{denominator}"))
    if factor == 1.0:
        assert "SI, no conversion" in note
    else:
        assert f"x {factor:.10g}" in note


def test_g_over_n_with_si_dataset_164(tmp_path, reference):
    """The issue's file: accelerance in g/N, record 9 label 'g', a dataset 164 saying SI."""
    path = write_variant(tmp_path / "g.uff", "g")
    assert pyuff.UFF(str(path)).read_sets(0)["units_code"] == 1
    measured = read_measured(path)
    _assert_same(measured, reference)
    # Read as SI the values would be 9.81 times too small: the ratio is g, not 1.
    raw = pyuff.UFF(str(path)).read_sets(1)["data"][1:]
    ratio = np.abs(reference.complex_frf[:, 0]) / np.abs(raw / (2 * np.pi * reference.frequencies_hz) ** 2)
    np.testing.assert_allclose(ratio, G, rtol=1e-10)


def test_whole_frf_label_in_record_9(tmp_path, reference):
    """Some exports write the whole unit (g/N) in record 9 and NONE in record 10."""
    path = write_variant(tmp_path / "gn.uff", "g", label="g/N")
    sets = pyuff.UFF(str(path)).read_sets()
    for s in sets:
        if s["type"] == 58:
            s["orddenom_axis_units_lab"] = "NONE"
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=True)
    _assert_same(read_measured(path), reference)


def test_unlabelled_data_follow_dataset_164(tmp_path, reference):
    """No units labels: the unit system of dataset 164 (IN: inch, pound force; file units per SI unit)."""
    system = {"units_code": 7, "units_description": "IN", "length": 1 / INCH, "force": 1 / LBF}
    path = write_variant(tmp_path / "in.uff", "in/s^2", denominator="lbf", system=system, label="NONE")
    sets = pyuff.UFF(str(path)).read_sets()
    for s in sets:
        if s["type"] == 58:
            s["orddenom_axis_units_lab"] = "NONE"
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=True)
    measured = read_measured(path)
    _assert_same(measured, reference)
    assert any("dataset 164" in n for n in measured.notes)


@pytest.mark.parametrize("unit, label, ordinate_type, needles", [
    ("g", "furlong/fortnight", None, ["dataset 2", "'furlong/fortnight'"]),
    ("g", "g", 8, ["dataset 2", "'g'", "acceleration", "data type 8"]),       # g on a displacement
    ("mm/s", "mm/s", 12, ["dataset 2", "'mm/s'", "velocity", "data type 12"]),
])
def test_unknown_or_contradicting_label_is_refused(tmp_path, unit, label, ordinate_type, needles):
    path = write_variant(tmp_path / "bad.uff", unit, label=label, ordinate_type=ordinate_type)
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    for needle in needles:
        assert needle in str(info.value)
    assert str(path) in str(info.value)


def test_unknown_force_label_and_bad_exponents_are_refused(tmp_path):
    path = write_variant(tmp_path / "f.uff", "g")
    sets = pyuff.UFF(str(path)).read_sets()
    sets[3]["orddenom_axis_units_lab"] = "kgf"
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=True)
    with pytest.raises(MeasuredDataError, match=r"dataset 4 .*record 10.*'kgf'"):
        read_measured(path)
    path = write_variant(tmp_path / "e.uff", "g", exponents={"ordinate_len_unit_exp": 1,
                                                             "ordinate_force_unit_exp": 1})
    with pytest.raises(MeasuredDataError, match=r"dataset 2 .*record 9: unit exponents"):
        read_measured(path)


def test_unit_tables():
    assert frf_unit("g/N") == ("accelerance", G)
    assert frf_unit("(m/s^2)/lbf") == ("accelerance", 1 / LBF)
    assert frf_unit("mm/s/N") == ("mobility", 1e-3)
    assert frf_unit("in/kN") == ("receptance", INCH / 1e3)
    assert math.isclose(frf_unit("in/s^2/lbf")[1], 0.0254 / 4.4482216152605)
    with pytest.raises(ValueError, match="'MN'"):
        frf_unit("m/MN")


# -- CSV ---------------------------------------------------------------------------------------------
def _csv(reference, values, header_extra="", unit_column=None):
    f = reference.frequencies_hz[200:204]
    rows = [f"{header_extra}response,reference,frequency_hz,real,imag" + (",unit" if unit_column else "")]
    for i, fi in enumerate(f):
        for j in range(2):
            v = values[200 + i, j]
            rows.append(f"{j + 1}:+z,5:+z,{float(fi)!r},{float(v.real)!r},{float(v.imag)!r}" + (f",{unit_column[j]}" if unit_column
                                                                            else ""))
    return "\n".join(rows) + "\n"


def test_csv_unit_per_file_and_per_row(tmp_path, reference):
    f = reference.frequencies_hz[:, None]
    accelerance_g = reference.complex_frf * -(2 * np.pi * f) ** 2 / G
    mobility_mm = reference.complex_frf * (2j * np.pi * f) * 1e3 * LBF
    path = tmp_path / "g.csv"
    path.write_text(_csv(reference, accelerance_g, header_extra="# unit = g/N\n"))
    m = read_measured(path)
    np.testing.assert_allclose(m.complex_frf, reference.complex_frf[200:204, :2], rtol=1e-12)
    assert m.units == ("g/N", "g/N") and m.kinds == ("accelerance",) * 2
    mixed = np.column_stack([accelerance_g[:, 0], mobility_mm[:, 1]])
    path = tmp_path / "rows.csv"
    path.write_text(_csv(reference, mixed, unit_column=["g/N", "mm/s/lbf"]))
    m = read_measured(path)
    np.testing.assert_allclose(m.complex_frf, reference.complex_frf[200:204, :2], rtol=1e-12)
    assert m.kinds == ("accelerance", "mobility")


def test_csv_unknown_unit_and_kind_clash_are_refused(tmp_path, reference):
    path = tmp_path / "bad.csv"
    path.write_text(_csv(reference, reference.complex_frf, header_extra="# unit = furlong/N\n"))
    with pytest.raises(MeasuredDataError, match=r"bad.csv: line 1: .*'furlong/N'"):
        read_measured(path)
    path.write_text(_csv(reference, reference.complex_frf, header_extra="# kind = mobility\n# unit = g/N\n"))
    with pytest.raises(MeasuredDataError, match=r"line 4: unit 'g/N' is a accelerance, but the row's kind is "
                                                r"mobility"):
        read_measured(path)


def test_parquet_unit_metadata_and_column(tmp_path, reference):
    import pyarrow as pa
    import pyarrow.parquet as pq

    f = reference.frequencies_hz[200:204]
    z = reference.complex_frf[200:204, 0] * -(2 * np.pi * f) ** 2 / G  # g/N
    columns = {"response": ["1:+z"] * 4, "reference": ["5:+z"] * 4, "frequency_hz": f, "real": z.real,
               "imag": z.imag}
    table = pa.table(columns).replace_schema_metadata({"unit": "g/N"})
    pq.write_table(table, tmp_path / "g.parquet")
    m = read_measured(tmp_path / "g.parquet")
    np.testing.assert_allclose(m.complex_frf[:, 0], reference.complex_frf[200:204, 0], rtol=1e-12)
    pq.write_table(pa.table({**columns, "unit": ["gee/N"] * 4}), tmp_path / "bad.parquet")
    with pytest.raises(MeasuredDataError, match=r"bad.parquet: row 1: .*'gee/N'"):
        read_measured(tmp_path / "bad.parquet")
