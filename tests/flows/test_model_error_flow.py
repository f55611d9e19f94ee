"""``python -m flows.model_error`` on a finished run: the run's tet10 model refined, its record and residuals
written, the verdict printed; a run it cannot take refused with exit 2."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from benchmarks.make.cases import build, fem_data
from flows import model_error, update


@pytest.mark.slow
def test_the_model_error_of_a_finished_run_is_written_and_said(tmp_path, monkeypatch, capsys, prefect_harness):
    """A clean case of the generator's tet10 block (data of a mesh half the model's size, noise with a floor and
    force noise), updated by the default command (its budget cut: the mesh's misfit would send it on global cycles),
    then sized against its refined mesh."""
    monkeypatch.setattr(fem_data, "CACHE", tmp_path / "cache")
    build.structure_info("tiny_block", tmp_path)
    build.make_case({"id": "blk", "structure": "tiny_block", "kind": "none", "seed": 5, "expected": "noise",
                     "set": "t"}, tmp_path)
    model_file = tmp_path / "structures" / "tiny_block" / "model.toml"
    runs = tmp_path / "runs"
    assert update.main(["--model", str(model_file), "--measured", str(tmp_path / "t" / "blk" / "measured.csv"),
                        "--runs-dir", str(runs), "--run-id", "blk", "--max-fe-evaluations", "30"]) == 0
    capsys.readouterr()
    assert model_error.main(["--run-id", "blk", "--runs-dir", str(runs)]) == 0
    out = capsys.readouterr().out
    folder = runs / "blk" / "model_error"
    record = json.loads((folder / "model_error.json").read_text())
    assert record["fine_dofs"] > 5 * record["model_dofs"] and len(record["bias"]) == 2
    assert 0 < record["rms_floor"] and record["rms_beyond"] < record["rms_data"]
    table = pd.read_parquet(folder / "residuals.parquet")
    assert list(table.columns) == ["frequency_hz", "sensor", "data_residual", "floor_residual"]
    assert (table["data_residual"] ** 2).mean() == pytest.approx(record["rms_data"] ** 2, rel=1e-9)
    assert "mesh bias" in out and "beyond the mesh" in out
    assert model_error.main(["--run-id", "nothing", "--runs-dir", str(runs)]) == 2
    assert "no summary.json" in capsys.readouterr().err
