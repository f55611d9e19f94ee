"""Route B inside the flows: a deck whose ``[[parameters]]`` are factors on its numbers, one ccx run per FE run.

A tiny deck (the example's cylindrical S8R panel on a 4 x 4 mesh, benchmarks/make/shell_panel.py), two
parameters: one segment's ``*SHELL SECTION`` thickness by ``kind``, another's by the general card form. The
measured FRF is ccx's own at the true thicknesses (noise free), so the update must find them to the accuracy
of its forward differences. Bad parameters exit 2 before any FE run, naming the model file's key and the deck.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmarks.make import shell_panel
from flows import update
from flows.config import UpdateConfig

pytestmark = pytest.mark.skipif(shutil.which("ccx") is None, reason="ccx not installed (apt-get install calculix-ccx)")
TRUTH = np.array([0.06, -0.05])
TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run

TOML = """units = "SI"
solver = "calculix"
deck = "panel.inp"
solver_timeout = 60.0
n_modes = 15

[damping]
a = 2.0
b = 2e-6

[[parameters]]
name = "t_root_low"
kind = "shell_thickness"
elset = "ROOT_LOW"
bounds = [-0.3, 0.3]

[[parameters]]
name = "t_tip_high"
card = "*SHELL SECTION"
elset = "TIP_HIGH"
line = 1
field = 1
bounds = [-0.3, 0.3]
{sensors}
[[excitations]]
nset = "TIP_CORNER"
direction = "z"
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    """model.toml, panel.inp and measured.csv (ccx's FRF at TRUTH on the same deck, 8 lines, 7 sensors)."""
    from fe_core.io import read_model

    folder = tmp_path_factory.mktemp("route-b")
    cards, ids = shell_panel.panel(4, 4)
    (folder / "panel.inp").write_text(cards)
    sensors = "".join(f'\n[[sensors]]\nnode = {ids[shell_panel.point(u, v)]}\ndirection = "{d}"\n'
                      for u, v, d in shell_panel.SENSORS)
    (folder / "model.toml").write_text(TOML.format(sensors=sensors))
    model = read_model(folder / "model.toml").with_workdir(folder / "truth")
    f0 = model.natural_frequencies(np.zeros(2), 2)
    freqs = np.sort(np.concatenate([f * np.array([0.9, 0.96, 1.04, 1.1]) for f in f0]))
    u = np.abs(model.parameter_frf(TRUTH, freqs))
    rows = ["sensor,frequency_hz,amplitude"] + [f"{j + 1},{float(f)!r},{float(u[k, j])!r}"
                                                for k, f in enumerate(freqs) for j in range(u.shape[1])]
    (folder / "measured.csv").write_text("\n".join(rows) + "\n")
    return folder


def _config(tiny: Path, runs: Path, run_id: str) -> UpdateConfig:
    return UpdateConfig(model=str(tiny / "model.toml"), measured=str(tiny / "measured.csv"), run_id=run_id,
                        runs_dir=str(runs), n_jobs=1, intervals=False, max_fe_evaluations=60)


def _summary(root: Path) -> dict:
    return {k: v for k, v in json.loads((root / "summary.json").read_text()).items() if k not in TIMING_KEYS}


@pytest.mark.slow
def test_a_black_box_update_converges_records_its_runs_and_resumes_after_a_crash(tiny, tmp_path, prefect_harness,
                                                                                  monkeypatch, check_summary):
    runs = tmp_path / "runs"
    summary = update.update_flow(_config(tiny, runs, "reference"))
    check_summary(runs / "reference")  # a deck's run: the one shape of every run (kind frf)
    x = np.array([summary["parameters"][n] for n in ("alpha_1", "alpha_2")])    # t_root_low, t_tip_high
    assert np.max(np.abs(x - TRUTH)) < 2e-3, x          # forward differences (step 1e-3) on noise-free data
    ref = runs / "reference"
    local = pd.read_parquet(ref / "iteration=1" / "stage=local" / "runs.parquet")
    # every Jacobian is m + 1 = 3 ccx runs of one round, each in its own complete folder under <run>/fe/
    assert (local["cost"] == 3.0).all() and (local["status"] == "ok").all()
    folders = [p for p in (ref / "fe").iterdir() if (p / "done.json").exists()]
    assert len(folders) >= 3 * len(local)                # (the nominal modes of the band check, too)

    # A crash during the ccx FE stage: after 5 of the forward-difference runs (the second of round 2's three).
    import tasks.fe_runs as fe_runs

    count = {"n": 0}

    def crash(name):
        if name.startswith("local-fd-run/"):
            count["n"] += 1
            if count["n"] == 5:
                raise RuntimeError("simulated crash")

    monkeypatch.setattr(fe_runs, "kill_point", crash)
    with pytest.raises(Exception):
        update.update_flow(_config(tiny, runs, "victim"))
    monkeypatch.undo()
    victim = runs / "victim"
    complete = {p.name: (p / "deck.log").stat().st_mtime_ns for p in (victim / "fe").iterdir()
                if (p / "done.json").exists()}
    assert len(complete) == 5
    broken = max(complete, key=complete.get)             # the last run's folder left incomplete: run again
    (victim / "fe" / broken / "done.json").unlink()
    update.update_flow(_config(tiny, runs, "victim"))
    assert _summary(victim) == _summary(ref)
    rerun = [n for n, t in complete.items() if (victim / "fe" / n / "deck.log").stat().st_mtime_ns != t]
    assert rerun == [broken]                             # the complete folders were read, not run again


def test_a_rejected_deck_is_a_failed_fe_run_quoting_ccx(tiny, tmp_path):
    from tasks.fe_runs import evaluate_sample
    from tasks.problem import ModelRef, model_checksum

    folder = tmp_path / "model"
    shutil.copytree(tiny, folder, ignore=shutil.ignore_patterns("truth"))
    deck = folder / "panel.inp"
    deck.write_text(deck.read_text().replace("CLAMP, 1, 6", "NOSUCH, 1, 6"))
    path = folder / "model.toml"
    ref = ModelRef(str(path), str(path), model_checksum(path), str(tmp_path / "fe"))
    df = evaluate_sample(ref, 7, np.zeros(2), np.array([60.0, 70.0]))
    assert (df["status"] == "failed").all() and df["real"].isna().all()
    assert "CcxError" in df["message"].iloc[0] and "*ERROR" in df["message"].iloc[0]
    assert "NOSUCH" in df["message"].iloc[0]


@pytest.mark.parametrize("edit, key, needle", [
    (lambda t: t.replace('elset = "ROOT_LOW"', 'elset = "NOPE"'), "parameters[0].elset",
     "*ELSET 'NOPE' is not in the deck"),
    (lambda t: t.replace("field = 1", "field = 3"), "parameters[1].field", "panel.inp:"),
    (lambda t: t.replace("line = 1", "line = 2"), "parameters[1].line", "has no data line 2"),
    (lambda t: t.replace('card = "*SHELL SECTION"', 'card = "*SPRING"'), "parameters[1].card",
     "has no *SPRING card"),
    (lambda t: t.replace('kind = "shell_thickness"', 'kind = "radius"'), "parameters[0].kind", "unknown kind"),
])
def test_a_parameter_that_names_no_number_of_the_deck_exits_2(tiny, tmp_path, capsys, edit, key, needle):
    folder = tmp_path / "model"
    folder.mkdir()
    shutil.copy(tiny / "panel.inp", folder)
    (folder / "model.toml").write_text(edit((tiny / "model.toml").read_text()))
    runs = tmp_path / "runs"
    code = update.main(["--model", str(folder / "model.toml"), "--measured", str(tiny / "measured.csv"),
                        "--run-id", "x", "--runs-dir", str(runs)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"{folder / 'model.toml'}: key '{key}'" in err and needle in err, err
    assert "Traceback" not in err and not (runs / "x").exists()
