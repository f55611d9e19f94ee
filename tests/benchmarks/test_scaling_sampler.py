"""The scaling benchmark's record of where the memory peaked: the log line stamped at or before the peak."""

from __future__ import annotations

import time

from benchmarks.scaling import line_at, _write_series

LOG = """model: sensor 1 'a': nearest node 3
04:20:55.848 | INFO    | Flow run 'cycle-1' - cycle 1: local converged
04:21:40.635 | INFO    | Flow run 'cycle-2' - cycle 2: global converged
warning: a line without a stamp
04:21:47.595 | INFO    | Task run 'model-vtu-8d0' - Finished in state Completed()
"""


def _at(hms: str, ms: int = 0) -> float:
    day = time.localtime()
    h, m, s = (int(v) for v in hms.split(":"))
    return time.mktime((day.tm_year, day.tm_mon, day.tm_mday, h, m, s, 0, 0, -1)) + ms / 1000


def test_the_line_at_a_time_is_the_last_stamped_before_it():
    assert "cycle 2: global" in line_at(LOG, _at("04:21:47", 100))
    assert "model-vtu" in line_at(LOG, _at("04:21:47", 600))
    assert "cycle 1" in line_at(LOG, _at("04:20:55", 848))
    assert line_at(LOG, _at("04:20:55", 847)) is None
    assert "model-vtu" in line_at(LOG, _at("05:00:00"))


def test_the_series_is_written_from_its_first_sample(tmp_path):
    path = tmp_path / "m.csv"
    _write_series(path, [(100.0, 1.0, 0.9), (101.5, 2.25, 2.0)])
    assert path.read_text().splitlines() == ["t_s,tree_rss_gb,tree_pss_gb", "0.0,1.000,0.900", "1.5,2.250,2.000"]
