"""A run of the default update, its model.vtu and its report on a model whose sensors and hammer lie between
nodes (``point_placement = "interpolate"``): the path reads the general output and load vectors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import report, update
from tasks.model_vtu import VTU_NAME
from tasks.report.mesh import SEGMENTS_PNG

TRUTH = np.array([0.2, -0.15])
FREQS = np.array([150.0, 220.0, 260.0, 320.0, 360.0, 420.0])
#: Off every node of the 6 x 2 x 1 and the 12 x 4 x 2 tet10 boxes (top face, side face, top face).
SENSORS = ("[0.2871, 0.0063, 0.03]", "[0.2937, 0.04, 0.0211]", "[0.1623, 0.0071, 0.03]")
HAMMER = "[0.2962, 0.0137, 0.03]"


def _between_nodes(model_file: Path) -> Path:
    text = model_file.read_text()
    for old, new in zip(("[0.3, 0.0, 0.03]", "[0.3, 0.04, 0.03]", "[0.15, 0.0, 0.03]"), SENSORS):
        text = text.replace(f"point = {old}", f"point = {new}")
    text = 'point_placement = "interpolate"\n' + text.replace("point = [0.3, 0.02, 0.03]", f"point = {HAMMER}")
    model_file.write_text(text)
    return model_file


@pytest.mark.slow
def test_an_update_report_and_vtu_of_a_model_read_between_nodes(tmp_path, prefect_harness, reduced_settings,
                                                                box_model_writer):
    from fe_core.io import read_model

    model_file = _between_nodes(box_model_writer(tmp_path / "box"))
    model = read_model(model_file)
    assert sum("between nodes" in p for p in model.placements) == 5   # 3 sensors, the hammer's 2 DOFs
    fine = read_model(_between_nodes(box_model_writer(tmp_path / "fine", cells=(12, 4, 2))))
    Z = np.abs(fine.frf(TRUTH, FREQS))
    measured = tmp_path / "measured.csv"
    pd.DataFrame({"sensor": np.tile([1, 2, 3], FREQS.size), "frequency_hz": np.repeat(FREQS, 3),
                  "amplitude": Z.ravel()}).to_csv(measured, index=False)
    config = update.UpdateConfig(run_id="between", runs_dir=str(tmp_path / "runs"), model=str(model_file),
                                 measured=str(measured), **dict(reduced_settings, max_iterations=1, polish=False))
    summary = update.update_flow(config)
    root = Path(summary["run_folder"])
    assert set(summary["parameters"]) >= {"alpha_1", "alpha_2"}
    assert (root / VTU_NAME).exists()
    page = Path(report.report_flow(str(root)))
    assert (page.parent / SEGMENTS_PNG).stat().st_size > 20000
