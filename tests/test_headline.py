"""The headline benchmark's readers (benchmarks/headline/parse.py): a "within" bound rounds up, tables read by name.

The headline page states "every factor within X of the truth" with X from ``up``: rounding to nearest could
state a bound the run does not meet. Tables printed by the benchmarks repeat column names (the Jacobian's
"in FE runs" for the Krylov and the direct method): the first must stay the first.
"""

from __future__ import annotations

import json
import math
import shutil

import pytest

from benchmarks.headline import parse as P


@pytest.mark.parametrize("x, text", [(0.000461, "0.00047"), (0.027, "0.027"), (0.02701, "0.028"), (6.71e-11, "6.8e-11"),
                                     (0.00021, "0.00021"), (1.0, "1.0"), (0.0, "0")])
def test_up_is_a_bound(x, text):
    assert P.up(x) == text
    assert float(P.up(x)) >= x


def test_percent_rounds_up():
    assert P.percent(0.00871) == "0.9 %" and P.percent(0.009) == "0.9 %" and P.percent(0.0091) == "1.0 %"
    assert P.span([3, 1, 2]) == "1-3" and P.span([2.0, 2.0], "{:.1f}") == "2.0" and P.span([math.nan]) == "-"


def test_markdown_rows_keep_the_first_of_a_repeated_column():
    text = ("noise\n| model | in FE runs | direct | in FE runs |\n|---|---|---|---|\n| benchmark | 2.1 | 347 ms | 22 |\n"
            "| bracket | 1.0 | skipped | - |\nafter\n")
    rows = P.markdown_rows(text, "model")
    assert [r["in FE runs"] for r in rows] == ["2.1", "1.0"]
    assert rows[0]["in FE runs 2"] == "22"
    with pytest.raises(ValueError):
        P.markdown_rows(text, "case")


def test_json_tail_and_summary_shapes(tmp_path):
    """The current summary and both shapes from before its schema (FRF pairs, modal nested) read alike."""
    import json

    assert P.json_tail('log line\n[\n {"a": 1}\n]\n') == [{"a": 1}]
    current = {"schema_version": 1, "kind": "frf", "parameters": {"a": 0.1, "b": -0.2}, "fe_evaluations": 7,
               "intervals": {"a": {"lower95": 0.0, "upper95": 0.2, "sd": 0.05},
                             "b": {"lower95": -0.1, "upper95": 0.0, "sd": 0.03}}}
    plain = {"parameters": {"a": 0.1, "b": -0.2}, "intervals": {"a": [0.0, 0.2], "b": [-0.1, 0.0]}, "fe_evaluations": 7}
    nested = {"kind": "modal update", "parameters": {"a": {"value": 0.1, "lower95": 0.0, "upper95": 0.2, "sd": 0.05},
                                                     "b": {"value": -0.2, "lower95": -0.1, "upper95": 0.0, "sd": 0.03}},
              "fe_runs": 7}
    for k, record in enumerate((current, plain, nested)):
        (tmp_path / str(k)).mkdir()
        (tmp_path / str(k) / "summary.json").write_text(json.dumps(record))
        s = P.summary(tmp_path / str(k))
        assert P.estimate(s).tolist() == [0.1, -0.2] and P.fe_runs(s) == 7
        assert P.covered(P.intervals(s), [0.1, -0.2]) == 1          # b's interval misses -0.2
    assert s["kind"] == "modal" and s["intervals"]["b"]["sd"] == 0.03
    assert P.intervals({"parameters": {"a": 0.0}, "intervals": {"a": {"lower95": None, "upper95": None, "sd": None}}
                        }).tolist() == [[-math.inf, math.inf]]      # a parameter the data do not pin down


def test_a_row_under_the_invocations_lock_is_recorded_as_locked(tmp_path, monkeypatch):
    """The command holds the heavy-job lock for all its rows by default and runs each row without a lock of its
    own: the rows must still say they ran locked (the page said "without the heavy-job lock" for such a run)."""
    from types import SimpleNamespace

    import benchmarks.headline as H

    monkeypatch.setattr(H, "REPO", tmp_path)
    monkeypatch.setattr(H, "WORK", tmp_path / "runs" / "headline")
    row = SimpleNamespace(key="k", env={}, commands=[(["json.tool", "--help"], {})],
                          summarise=lambda out, log, timing: ("read", {"n": 1}))
    held = H.run_row(row, None, held=True)
    assert held["locked"] and held["result"] == "read" and held["commands"][0]["exit"] == 0
    assert not H.run_row(row, None)["locked"]
    lock = tmp_path / "lock"
    lock.touch()
    assert H.run_row(row, lock)["locked"]


def test_only_some_rows_keeps_the_others_as_the_page_had_them(tmp_path, monkeypatch):
    """``--only ROW`` on a clone with no stored runs rewrote the page from that row alone (673 lines of other rows
    were lost): the page's records are committed beside it, and each row shows the newer of its local run and them."""
    from types import SimpleNamespace

    import benchmarks.headline as H
    import benchmarks.headline.__main__ as M

    for mod in (H, M):
        monkeypatch.setattr(mod, "REPO", tmp_path)
        monkeypatch.setattr(mod, "WORK", tmp_path / "runs" / "headline")
        monkeypatch.setattr(mod, "PAGE", tmp_path / "headline.md")
    monkeypatch.setattr(H, "RECORDS", tmp_path / "headline.json")
    monkeypatch.setattr(H, "README", tmp_path / "README.md")
    rows = [SimpleNamespace(key=k, what=k, details="d", note="", env={}, commands=[(["json.tool", "--help"], {})],
                            summarise=lambda out, log, timing, k=k: (f"result of {k}", {"k": k})) for k in "ab"]
    monkeypatch.setattr("benchmarks.headline.rows.ROWS", rows)
    old = {k: {**H.run_row(r, None), "date": "2020-01-01 00:00 UTC", "commit": "old"} for k, r in zip("ab", rows)}
    (tmp_path / "headline.json").write_text(json.dumps(old))
    shutil.rmtree(tmp_path / "runs")                                    # a fresh clone: nothing stored here
    assert M.main(["--only", "b", "--lock", "none", "--no-readme"]) == 0
    page = (tmp_path / "headline.md").read_text()
    assert "result of a" in page and "`old`" in page                   # row a as the page had it
    assert page.count("result of b") == 2 and page.count("`old`") == 3 # b rerun; `old` in header, a's cell, a's section
    kept = json.loads((tmp_path / "headline.json").read_text())
    assert kept["a"]["commit"] == "old" and kept["b"]["commit"] != "old"
    stale = {**old["a"], "date": "2019-01-01 00:00 UTC", "result": "stale"}  # an older local run loses to the page
    (tmp_path / "runs" / "headline" / "a").mkdir(parents=True)
    (tmp_path / "runs" / "headline" / "a" / "row.json").write_text(json.dumps(stale))
    assert H.current(["a"])["a"]["result"] == "result of a"
