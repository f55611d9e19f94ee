"""The residual figures read at a test system's line density: a label per line only for a few lines (the closure's
figure, the report's residual map)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tasks.closure.plot import _ticks, plot_residuals
from tasks.report.figures._style import FREQUENCY_LABELS, LABEL_EVERY_LINE_UP_TO


def test_few_lines_are_each_labelled_many_get_a_dozen_spread_over_the_band():
    few = np.array([10.0, 20.0, 35.0, 50.0])
    ticks, joins = _ticks(few)
    assert ticks.tolist() == [0, 1, 2, 3] and joins.size == 0
    band = np.arange(160.0, 1460.0)                             # hb07's 1 Hz lines
    ticks, joins = _ticks(band)
    assert ticks.size == FREQUENCY_LABELS and ticks[0] == 0 and ticks[-1] == band.size - 1
    assert np.all(np.diff(ticks) >= band.size // FREQUENCY_LABELS - 1) and joins.size == 0


def test_two_bands_side_by_side_are_marked_where_the_second_starts_and_dropped_lines_are_not():
    dropped = np.delete(np.arange(100.0, 300.0), [5, 6, 40, 41, 42])  # lines left out here and there: 2-4 Hz gaps
    assert _ticks(dropped)[1].size == 0
    two = np.r_[np.arange(10.0, 50.0, 0.5), np.arange(300.0, 340.0, 0.5)]
    assert _ticks(two)[1].tolist() == [80]


@pytest.mark.parametrize("lines", [LABEL_EVERY_LINE_UP_TO // 2, 1270])
def test_the_figure_is_written_for_few_and_many_lines(tmp_path, lines):
    rng = np.random.default_rng(3)
    freqs = np.linspace(100.0, 100.0 + lines, lines)
    rows = [(s, f, rng.normal(0, 0.05)) for s in (1, 2, 3, 4) for f in freqs]
    before = pd.DataFrame(rows, columns=["sensor", "frequency_hz", "residual"])
    after = before.assign(residual=before["residual"] / 10)
    before.to_parquet(tmp_path / "residual_before.parquet")
    after.to_parquet(tmp_path / "residual_after.parquet")
    info = {"residual_before": {"sigma": 0.01}, "error_before": 0.3, "error_after": 0.02,
            "effect": {"type": "point_mass", "location": "node 7", "parameter": "mass", "value": 0.2, "unit": "kg"}}
    (tmp_path / "closure.json").write_text(json.dumps(info))
    png = plot_residuals(tmp_path)
    assert png == tmp_path / "residuals.png" and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("lines, labels", [(20, 20), (1270, 12)])
def test_the_reports_residual_map_labels_each_of_a_few_lines_and_a_dozen_of_many(monkeypatch, tmp_path, lines, labels):
    import tasks.report.figures.frf as frf

    shown = {}
    monkeypatch.setattr(frf, "_save", lambda fig, path: shown.setdefault("fig", fig) and path)
    freqs = np.arange(100.0, 100.0 + lines)
    df = pd.DataFrame([(s, f, 0.01 * np.sin(f)) for s in (1, 2, 3) for f in freqs],
                      columns=["sensor", "frequency_hz", "residual"])
    frf.plot_residual_maps({"before": df, "after": df.assign(residual=df["residual"] / 2)}, tmp_path / "map.png")
    for ax in shown["fig"].axes[:2]:
        texts = [t.get_text() for t in ax.get_xticklabels()]
        assert len(texts) == labels and texts[0] == "100" and texts[-1] == f"{100 + lines - 1}"
