"""Every problem of a measured file in one message (up to 20 listed, then the count of the rest), exit 2.

A user who fixes one fault and reruns should not meet the next: the readers check every row, dataset and
channel they can check independently and report them together.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import pyuff

from flows import update
from tasks.io.measured import MeasuredDataError, read_measured
from tasks.io.measured.problems import MAX_LISTED

REPO = Path(__file__).resolve().parents[2]
BENCHMARK = REPO / "data" / "benchmark" / "measured.csv"
LINES = BENCHMARK.read_text().splitlines()  # header + 72 rows: sensor,frequency_hz,amplitude,real,imag

_spec = importlib.util.spec_from_file_location("units_helpers", Path(__file__).parent / "test_measured_units.py")
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)


def _with(changes: dict[int, str]) -> str:
    """The benchmark CSV with lines (1-based, header = 1) replaced."""
    lines = list(LINES)
    for number, text in changes.items():
        lines[number - 1] = text
    return "\n".join(lines) + "\n"


def _field(number: int, field: int, value: str) -> str:
    cells = LINES[number - 1].split(",")
    cells[field] = value
    return ",".join(cells)


def test_three_faults_of_a_csv_in_one_message(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(_with({3: _field(3, 2, "abc"), 10: _field(10, 1, "-5"), 20: LINES[19] + ",7"}))
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: 3 problems:")
    assert "line 3: amplitude 'abc' is not a number" in message
    assert "line 10: frequency_hz -5.0 is not > 0" in message
    assert "line 20: 6 fields, the header has 5" in message


def test_more_than_twenty_faults_are_counted(tmp_path):
    path = tmp_path / "m.csv"
    changes = {n: _field(n, 2, f"x{n}") for n in range(2, 2 + MAX_LISTED + 5)}  # 25 bad amplitudes
    path.write_text(_with(changes))
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value).splitlines()
    assert message[0] == f"{path}: 25 problems:"
    assert len(message) == 1 + MAX_LISTED + 1 and message[-1].strip() == "... and 5 more problems"
    assert message[1].strip() == "line 2: amplitude 'x2' is not a number"


def test_two_faulty_uff_datasets_in_one_message(tmp_path):
    path = _helpers.write_variant(tmp_path / "m.uff", "g")
    sets = pyuff.UFF(str(path)).read_sets()
    sets[3]["ordinate_axis_units_lab"] = "gee"      # dataset 4: unknown label
    sets[7]["ordinate_spec_data_type"] = 8          # dataset 8: g on a displacement
    sets[11]["orddenom_axis_units_lab"] = "kgf"     # dataset 12: unknown force
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=True)
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path)
    message = str(info.value)
    assert message.startswith(f"{path}: 3 problems:")
    for needle in ("dataset 4 (response 2:+z, reference 5:+z): record 9: units label: unknown response unit 'gee'",
                   "dataset 8 (response 4:+z, reference 5:+z): record 9: units label 'g' is a acceleration, but the "
                   "data type 8 says displacement",
                   "dataset 12 (response 6:+z, reference 5:+z): record 10: units label: unknown force unit 'kgf'"):
        assert needle in message


def test_the_update_exits_2_with_every_problem(tmp_path, capsys):
    path = tmp_path / "m.csv"
    path.write_text(_with({5: _field(5, 3, "nan?"), 40: _field(40, 0, "0")}))
    code = update.main(["--run-id", "bad", "--runs-dir", str(tmp_path / "runs"), "--measured", str(path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "2 problems" in err and "line 5: real 'nan?' is not a number" in err
    assert "line 40: sensor 0.0 is not an integer >= 1" in err
    assert "Traceback" not in err and not (tmp_path / "runs" / "bad").exists()
