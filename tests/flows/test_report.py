"""The run report: built from small stored runs (single, repeats, conventional, with polish and closure).

The runs are made once per module with the REDUCED configuration of
``tests/flows/conftest.py`` under Prefect's test harness.
"""

from __future__ import annotations

import base64
import json
import re
import shutil
import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib import image as mpimg

from flows import report
from flows.config import REPO, UpdateConfig
from tasks.io.measured import read_measured
from tasks.report.data import ReportError, best_so_far, load_run, residual_frame

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

SINGLE_FIGURES = {"frf_overview.png", "frf_zoom.png", "residual_map.png", "error_overall.png", "error_per_sensor.png",
                  "samples.png", "parameters.png", "distributions.png", "training_time.png",
                  "mesh_segments.png", "mesh_factors.png"}
REPEATS_FIGURES = {"repeats_error.png", "repeats_parameters.png", "repeats_error_trend.png", "training_time.png",
                   "frf_overview.png", "frf_zoom.png", "residual_map.png", "mesh_segments.png", "mesh_factors.png"}


@pytest.fixture(scope="module")
def harness(prefect_harness):
    """The session's Prefect test server (tests/flows/conftest.py)."""
    return prefect_harness


def _reduced() -> dict:
    # The REDUCED settings of tests/flows/conftest.py (imported by path: test dirs are not packages).
    import importlib.util

    spec = importlib.util.spec_from_file_location("flows_conftest", Path(__file__).with_name("conftest.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return dict(mod.REDUCED)


@pytest.fixture(scope="module")
def runs(tmp_path_factory, harness) -> Path:
    from fe_core.benchmark import ALPHA_ACTUAL
    from flows import update

    runs_dir = tmp_path_factory.mktemp("report") / "runs"
    base = dict(_reduced(), runs_dir=str(runs_dir), true_parameters=ALPHA_ACTUAL.tolist())
    update.update_flow(UpdateConfig(run_id="single", **base))
    update.update_flow(UpdateConfig(run_id="repeats", **{**base, "repeats": 2}))
    update.update_flow(UpdateConfig(run_id="conventional", **{**base, "repeats": 2, "strategy": "conventional",
                                                                "conventional_samples": 12}))
    # The default strategy (hybrid) on the benchmark, with its intervals: 18 FE runs with Jacobians.
    update.update_flow(UpdateConfig(run_id="hybrid", **{**base, "strategy": "hybrid", "intervals": True,
                                                          "max_fe_evaluations": 240}))
    return runs_dir


@pytest.fixture(scope="module")
def single_report(runs) -> Path:
    return Path(report.report_flow(str(runs / "single")))


def check_report(page: Path, expected: set[str]) -> str:
    """Every expected PNG exists, is a decodable non-empty PNG, and the page embeds and names each PNG."""
    folder = page.parent
    assert page.exists() and page.name == "report.html"
    pngs = {p.name for p in folder.glob("*.png")}
    assert expected <= pngs, expected - pngs
    text = page.read_text()
    embedded = dict(re.findall(r'<img src="data:image/png;base64,([^"]+)" alt="([^"]+)"', text))
    embedded = {name: data for data, name in embedded.items()}
    for name in pngs:
        raw = (folder / name).read_bytes()
        assert raw[:8] == PNG_SIGNATURE and len(raw) > 5000, name
        width, height = struct.unpack(">II", raw[16:24])
        assert width >= 400 and height >= 300, (name, width, height)
        pixels = mpimg.imread(folder / name)
        assert pixels.shape[:2] == (height, width) and pixels.std() > 0.01, name  # not a blank image
        assert f'href="{name}"' in text, name
        assert base64.b64decode(embedded[name]) == raw, name
    assert "http://" not in text and "https://" not in text  # self-contained
    return text


def test_report_of_a_single_run_has_every_figure_and_the_page_embeds_them(single_report):
    page = single_report
    text = check_report(page, SINGLE_FIGURES)
    for figure in ("Figure 3", "Figures 4 and 5", "Figures 6-8", "Figure 9"):
        assert figure in text
    assert (page.parent / "cache" / "frf_dense.parquet").exists()


def test_every_run_and_every_repeat_writes_its_model_vtu(runs):
    """The benchmark's 544 hex8 cells with the summary's alpha per cell (tests/flows/test_model_pictures.py
    checks the modes)."""
    import meshio

    for folder in (runs / "single", runs / "repeats" / "repeat=0", runs / "conventional" / "repeat=1"):
        grid = meshio.read(folder / "model.vtu")
        summary = json.loads((folder / "summary.json").read_text())
        alpha = np.array(list(summary["parameters"].values()))
        assert grid.cells[0].type == "hexahedron" and len(grid.cells[0].data) == 544
        np.testing.assert_array_equal(grid.cell_data["alpha"][0], alpha[grid.cell_data["segment"][0]])
        assert len(grid.point_data) == 6


def test_every_summary_has_the_one_shape_and_a_broken_one_is_refused(runs, check_summary):
    """The module's runs (an FRF run, repeats of the paper's loop and of the conventional baseline, the hybrid with
    its intervals) validate against tasks/io/summary.schema.json; each way of breaking one is refused."""
    import copy

    import jsonschema

    kinds = {name: check_summary(runs / name)["kind"] for name in ("single", "repeats", "conventional", "hybrid")}
    assert kinds == {"single": "frf", "repeats": "repeats", "conventional": "repeats", "hybrid": "frf"}
    repeats = json.loads((runs / "repeats" / "summary.json").read_text())
    assert [r["run_id"] for r in repeats["runs"]] == ["repeats/repeat=0", "repeats/repeat=1"]
    assert repeats["parameters"] == pytest.approx(
        {n: np.mean([r["parameters"][n] for r in repeats["runs"]]) for n in repeats["parameters"]}, rel=1e-12)
    hybrid = json.loads((runs / "hybrid" / "summary.json").read_text())
    cov = np.array(hybrid["covariance"], float)
    sd = np.array([hybrid["intervals"][n]["sd"] for n in hybrid["parameters"]])
    np.testing.assert_allclose(sd, np.sqrt(np.diag(cov)), rtol=1e-12)

    def broken(summary, change):
        s = copy.deepcopy(summary)
        change(s)
        return s

    first = next(iter(hybrid["parameters"]))
    cases = {
        "no version": broken(hybrid, lambda s: s.pop("schema_version")),
        "another version": broken(hybrid, lambda s: s.update(schema_version=2)),
        "unknown kind": broken(hybrid, lambda s: s.update(kind="deck")),
        "intervals as pairs": broken(hybrid, lambda s: s["intervals"].update({first: [0.0, 1.0]})),
        "a parameter as a dict": broken(hybrid, lambda s: s["parameters"].update({first: {"value": 0.1}})),
        "intervals without covariance": broken(hybrid, lambda s: s.pop("covariance")),
        "a field nobody documented": broken(hybrid, lambda s: s.update(extra=1)),
        "a modal field in an FRF run": broken(hybrid, lambda s: s.update(chi2=1.0)),
        "an FRF run called modal": broken(hybrid, lambda s: s.update(kind="modal")),
        "stop reason missing": broken(hybrid, lambda s: s.pop("stop_reason")),
        "a repeat of another kind": broken(repeats, lambda s: s["runs"][0].update(kind="repeats")),
        "a repeat's parameters missing": broken(repeats, lambda s: s["runs"][1].pop("parameters")),
        "intervals of other parameters": broken(hybrid, lambda s: s["intervals"].pop(first)),
    }
    accepted = []
    for name, s in cases.items():
        try:
            check_summary(s)
        except AssertionError:
            continue
        accepted.append(name)
    assert accepted == []
    schema = json.loads((REPO / "tasks" / "io" / "summary.schema.json").read_text())
    with pytest.raises(jsonschema.ValidationError, match="is not of type 'number'"):
        jsonschema.validate(cases["a parameter as a dict"], schema, cls=jsonschema.Draft202012Validator)


def test_measured_amplitudes_recovered_from_the_run_equal_the_measurement_file(runs):
    data = load_run(runs / "single")
    measured = read_measured(REPO / "data" / "benchmark" / "measured.csv")
    wide = data.measured.pivot(index="frequency_hz", columns="sensor", values="amplitude")
    np.testing.assert_allclose(wide.index.to_numpy(), measured.frequencies_hz)
    np.testing.assert_allclose(wide.to_numpy(), measured.amplitude, rtol=1e-12)


def test_dense_updated_curve_at_the_measured_points_gives_the_runs_reported_error(runs, single_report):
    """The cached dense FE curve of the updated parameters, read at the measured frequencies,
    reproduces the overall error the updating run computed from its own FE stage."""
    data = load_run(runs / "single")
    dense = pd.read_parquet(runs / "single" / "report" / "cache" / "frf_dense.parquet")
    measured = read_measured(REPO / "data" / "benchmark" / "measured.csv")
    updated = dense[dense["curve"] == "updated"]
    np.testing.assert_allclose(updated[data.names].iloc[0].to_numpy(), list(data.summary["parameters"].values()))
    amp = np.hypot(updated["real"], updated["imag"]).to_numpy()
    at = {(round(f, 6), s): a for f, s, a in zip(updated["frequency_hz"], updated["sensor"], amp)}
    model = np.array([[at[(round(f, 6), s)] for s in range(1, 7)] for f in measured.frequencies_hz])
    error = np.mean(np.abs(model - measured.amplitude) / measured.amplitude)
    assert error == pytest.approx(data.summary["overall_error"], rel=1e-6)


def test_best_so_far_never_increases_and_with_the_polish_ends_at_the_summary(runs):
    data = load_run(runs / "single")
    best = best_so_far(data)
    assert list(best["iteration"]) == sorted(data.errors["iteration"].unique())
    assert np.all(np.diff(best["overall_error"]) <= 0)
    # The run's polish stage (tasks.polish) is picked up: its points and their errors.
    assert data.polish is not None and len(data.polish) == data.summary["polish"]["n"]
    final = min(best["overall_error"].iloc[-1], data.polish["overall_error"].min())
    assert final == pytest.approx(data.summary["overall_error"], rel=1e-12)
    assert best["fe_evaluations"].iloc[-1] + len(data.polish) == data.summary["fe_evaluations"]


@pytest.mark.parametrize("run_id, figures", [("repeats", ("10", "11")), ("conventional", ("12", "13"))])
def test_report_of_repeated_runs_draws_the_statistics_figures(runs, run_id, figures):
    page = Path(report.report_flow(str(runs / run_id)))
    text = check_report(page, REPEATS_FIGURES)
    summary = json.loads((runs / run_id / "summary.json").read_text())
    for n in figures:
        assert f"Figure {n}" in text
    assert f"{summary['repeats']['overall_error']['mean']:.4g}" in text  # the summary's statistics table
    assert "seed 11" in text and "seed 12" in text


def _add_closure_and_a_new_stage(root: Path) -> None:
    """What issue 5's close-the-loop step (tasks.closure) leaves in a run folder, and a stage added later."""
    summary = json.loads((root / "summary.json").read_text())
    (root / "iteration=1" / "stage=future-stage").mkdir()
    freqs = [106.0, 108.0, 110.0, 112.0, 114.0, 116.0, 285.0, 287.0, 289.0, 291.0, 293.0, 295.0]
    before = pd.DataFrame([{"frequency_hz": f, "sensor": s, "residual": 0.05 * np.sin(f + s)}
                           for f in freqs for s in range(1, 7)])
    after = before.assign(residual=0.1 * before["residual"])
    folder = root / "closure"
    folder.mkdir()
    before.to_parquet(folder / "residual_before.parquet")
    after.to_parquet(folder / "residual_after.parquet")
    amp = pd.DataFrame([{"frequency_hz": f, "sensor": s, "measured": 1e-5 / f, "alpha_only": 1.05e-5 / f,
                         "extended": 1.001e-5 / f} for f in freqs for s in range(1, 7)])
    amp.to_parquet(folder / "frf_closure.parquet")
    closure = {
        "verdict": "explained", "frf_table": "frf_closure.parquet",
        "effects": [{"step": 1, "type": "point_mass", "location": "node 412", "value": 0.05, "unit": "kg",
                     "explained": 0.97}],
        "decision": "added point_mass at node 412: residual before is structure",
        "effect": {"type": "point_mass", "location": "node 412", "value": 0.05, "unit": "kg"},
        "error_before": 0.05, "error_after": 0.006,
        "per_sensor_error_before": {f"sensor_{i}": 0.05 for i in range(1, 7)},
        "per_sensor_error_after": {f"sensor_{i}": 0.006 for i in range(1, 7)},
        "parameters_before": summary["parameters"],
        "parameters_after": {**summary["parameters"], "point_mass.mass": 0.05},
        "residual_before": {"rms": 0.035, "chi2": 3000.0, "p_chi2": 0.0},  # statistics, not a table
        "residual_after": {"rms": 0.0035, "chi2": 60.0, "p_chi2": 0.5},
        "candidates": [{"rank": 1, "type": "point_mass", "location": "node 412", "checked": True,
                        "linear_explained": 0.95, "explained": 0.97},
                       {"rank": 2, "type": "grounded_spring", "location": "node 300", "checked": True,
                        "linear_explained": 0.7, "explained": 0.72},
                       {"rank": 3, "type": "point_mass", "location": "node 413", "checked": False,
                        "linear_explained": 0.9, "explained": None}],
        "n_candidates": 3,
        "residual_tables": {"before": "residual_before.parquet", "after": "residual_after.parquet"},
    }
    (folder / "closure.json").write_text(json.dumps(closure))


def test_residual_tables_of_closure_json_are_read_in_every_documented_form(tmp_path):
    freqs = [106.0, 285.0]
    records = [{"frequency_hz": f, "sensor": s, "residual": 0.01 * s + f / 1e4} for f in freqs for s in (1, 2, 3)]
    expected = pd.DataFrame(records)
    expected.to_parquet(tmp_path / "r.parquet")
    matrix = [[0.01 * s + f / 1e4 for s in (1, 2, 3)] for f in freqs]
    columns = {k: [r[k] for r in records] for k in ("frequency_hz", "sensor", "residual")}
    for obj in (records, "r.parquet", matrix, columns):
        got = residual_frame(obj, tmp_path, freqs)
        pd.testing.assert_frame_equal(got.reset_index(drop=True), expected, check_dtype=False)
    for unusable in (None, {"rms": 0.03}, "missing.parquet", [[1.0, 2.0]]):
        assert residual_frame(unusable, tmp_path, freqs) is None


def test_closure_results_and_unknown_stages_are_reported_and_the_frf_cache_is_reused(runs, single_report, tmp_path,
                                                                                      monkeypatch):
    root = tmp_path / "extras"
    shutil.copytree(runs / "single", root)  # with its report/ folder and the cached dense FRF
    for png in (root / "report").glob("*.png"):
        png.unlink()
    _add_closure_and_a_new_stage(root)
    data = load_run(root)
    assert data.polish is not None
    assert "future-stage" in " ".join(data.notes) and "polish" not in " ".join(data.notes)

    def no_fe(*args, **kwargs):
        raise AssertionError("the FE model was called although the cached curves are valid")

    monkeypatch.setattr("fe_core.model_responses.ModelResponses.parameter_frf", no_fe)
    page = Path(report.report_flow(str(root)))
    text = check_report(page, SINGLE_FIGURES | {"closure_residuals.png", "closure_candidates.png", "closure_frf.png"})
    assert "Verdict: explained" in text
    assert "Close the loop" in text and "point_mass @ node 412" in text and "Polish-stage points" in text
    assert "<td>5%</td>" in text and "<td>0.6%</td>" in text  # overall errors before and after
    assert "future-stage" in text


#: What the report draws for a run of the default strategy: no sampling distributions or MRGP training times
#: (the hybrid's emulator is fitted inside its global stage, and this run needed none).
HYBRID_FIGURES = {"frf_overview.png", "frf_zoom.png", "residual_map.png", "error_overall.png", "error_per_sensor.png",
                  "samples.png", "parameters.png", "intervals.png", "mesh_segments.png", "mesh_factors.png"}


def test_report_of_a_default_strategy_run_draws_its_fe_runs_and_intervals(runs, capsys):
    assert report.main(["--run-id", "hybrid", "--runs-dir", str(runs)]) == 0
    page = Path(capsys.readouterr().out.strip().splitlines()[-1])
    text = check_report(page, HYBRID_FIGURES)
    data = load_run(runs / "hybrid")
    summary = json.loads((runs / "hybrid" / "summary.json").read_text())
    assert len(data.samples) == summary["fe_evaluations"] == 18 and data.polish is None
    assert set(data.stages["stage"]) == {"local", "check", "intervals"} and data.stages["known"].all()
    assert data.best()[2] == pytest.approx(summary["overall_error"])
    assert "Strategy hybrid" in text and "1 cycles and 18 FE runs (18 with their exact Jacobian" in text


def test_rerun_of_each_stage_of_a_default_strategy_run(runs, capsys):
    """From the stored inputs: the check and the intervals with another noise level, the local stage read back
    from its stored FE runs (none made again); the original stages are untouched."""
    from flows import update
    from tasks.fe_runs import read_fe_log
    from tasks.runstore import RunStore

    store = RunStore(runs / "hybrid")
    log_before = len(read_fe_log(store.root))
    check = store.stage_info(1, "check")
    assert check["at_floor"] and check["sigma_source"] == "none"  # the target was reached: no test made
    out = update.rerun_stage(store.root, 1, "check", noise=0.2)
    assert out.name.startswith("stage=check.rerun-noise0.2-") and store.stage_info(1, "check") == check
    out = update.rerun_stage(store.root, 1, "intervals", noise=0.01)
    iv, original = store.stage_info(1, out.name.split("=", 1)[1]), store.stage_info(1, "intervals")
    assert iv["noise_sigma"] == 0.01 and iv["interval_details"]["noise_source"] == "given"
    assert original["noise_sigma"] < 1e-6  # noise-free data: the estimated noise is round-off
    assert iv["intervals"]["alpha_1"][1] - iv["intervals"]["alpha_1"][0] > 1e3 * (
        original["intervals"]["alpha_1"][1] - original["intervals"]["alpha_1"][0])
    assert update.main(["rerun", "--run-id", "hybrid", "--runs-dir", str(runs), "--stage", "local"]) == 0
    folder = Path(capsys.readouterr().out.split("rerun written to ")[1].strip())
    again = pd.read_parquet(folder / "runs.parquet")
    pd.testing.assert_frame_equal(again, store.read_table(1, "local", "runs"))
    assert len(read_fe_log(store.root)) == log_before  # every FE run read back, none made again
    with pytest.raises(update.ConfigError, match="choose one of local, global, check, intervals"):
        update.rerun_stage(store.root, 1, "train")


def test_report_cli_refuses_a_missing_run_and_a_folder_without_manifest(tmp_path, capsys):
    assert report.main(["--run-id", "nope", "--runs-dir", str(tmp_path)]) == 2
    assert "no such run folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReportError, match="manifest.json"):
        load_run(tmp_path / "empty")
