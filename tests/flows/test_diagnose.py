"""flows.diagnose end to end: a reduced updating run on data with an undeclared point mass, then the closure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import diagnose as dg
from flows import update
from flows.config import REPO, UpdateConfig

DATA = REPO / "data" / "cases" / "three_plate_effects"
# The flow's plumbing needs the true effect and two rivals to check (the choice among every
# registered effect is tests/fe_core/test_closure.py's): a small library keeps the three closures cheap.
OPTIONS = dict(noise=0.005, effects=["point_mass", "grounded_spring", "segment_mass"])
CLOSURE_KEYS = {"effect", "error_before", "error_after", "parameters_before", "parameters_after", "candidates",
                "residual_tables", "per_sensor_error_before", "per_sensor_error_after", "decision"}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory, reduced_settings_frozen, prefect_harness):
    runs = tmp_path_factory.mktemp("runs")
    config = UpdateConfig(run_id="pm", runs_dir=str(runs), measured=str(DATA / "point_mass.csv"),
                          **dict(reduced_settings_frozen))
    update.update_flow(config)
    summary = dg.diagnose("pm", runs, **OPTIONS)
    again = dg.diagnose("pm", runs, **OPTIONS)
    return runs / "pm", summary, again


@pytest.mark.slow
def test_the_closure_of_a_reduced_run_names_the_point_mass_and_writes_its_tables(diagnosed, benchmark_model):
    root, summary, _ = diagnosed
    truth = json.loads((DATA / "truth.json").read_text())["data"]["point_mass.csv"]
    closure = root / "closure"
    on_disk = json.loads((closure / "closure.json").read_text())
    assert CLOSURE_KEYS <= set(on_disk)
    effect = on_disk["effect"]
    assert effect["type"] == "point_mass" and on_disk["candidates"][0]["type"] == "point_mass"
    node = int(effect["location"].split()[1])
    cells = benchmark_model.mesh.cells
    assert np.any(np.any(cells == node, axis=1) & np.any(cells == truth["node"], axis=1))
    assert effect["value"] == pytest.approx(truth["value"], rel=0.2)
    assert on_disk["error_after"] < on_disk["error_before"] / 5
    assert on_disk["parameters_run"] == json.loads((root / "summary.json").read_text())["parameters"]
    mass = f"point_mass@{effect['location']}.mass"  # one naming scheme: <kind>@<location>.<parameter>
    assert mass in on_disk["parameters_after"] and mass not in on_disk["parameters_before"]
    for key in ("before", "after"):
        table = pd.read_parquet(closure / on_disk["residual_tables"][key])
        assert list(table.columns[:3]) == ["frequency_hz", "sensor", "residual"] and len(table) == 72
    # The after-table is the final model's relative residual: its mean modulus is the error after.
    after = pd.read_parquet(closure / "residual_after.parquet")
    assert after["residual"].abs().mean() == pytest.approx(on_disk["error_after"], rel=1e-9)
    assert (closure / "residuals.png").stat().st_size > 10_000
    # Issue 18: the verdict, the effects in the order added, and the FRF of both models.
    assert on_disk["verdict"] == "explained" and [e["type"] for e in on_disk["effects"]] == ["point_mass"]
    assert on_disk["effects"][0]["value"] == pytest.approx(effect["value"], rel=1e-12)
    # Its kind holds the evidence in its place, and its node is among the locations that hold 95 % of it.
    first = on_disk["effects"][0]
    assert first["identified"] and first["evidence"] >= 0.95
    assert first["location"] in [loc["location"] for loc in first["locations"]] or first["locations_95"] > 10
    frf = pd.read_parquet(closure / on_disk["frf_table"])
    rel = (frf["extended"] - frf["measured"]).abs() / frf["measured"]
    assert rel.mean() == pytest.approx(on_disk["error_after"], rel=1e-9)
    ranks = pd.read_parquet(closure / on_disk["tables"]["candidates"])
    assert ranks["rank"].tolist() == list(range(1, len(ranks) + 1)) and ranks["checked"].iloc[0]


@pytest.mark.slow
def test_closure_json_has_intervals_and_covariance_of_alpha_and_the_effect(diagnosed, benchmark_model):
    """Issue 19: Laplace intervals of the extended model; the covariance against central differences."""
    import io

    from scipy import stats

    from fe_core.closure.effects import Applied, build_library, extended_frf

    root, summary, _ = diagnosed
    on_disk = json.loads((root / "closure" / "closure.json").read_text())
    names = list(on_disk["parameters_after"])
    mass = f"point_mass@{on_disk['effects'][0]['location']}.mass"
    assert list(on_disk["intervals"]) == names and names[-1] == mass
    assert on_disk["interval_method"] == "laplace" and on_disk["noise_sigma"] == 0.005  # --noise given
    d = on_disk["interval_details"]
    est = np.array([d["estimate"][n] for n in names])
    low, high = np.array([on_disk["intervals"][n] for n in names]).T
    cov = np.array(on_disk["covariance"])
    z = stats.norm.ppf(0.975)
    np.testing.assert_allclose(high - low, 2 * z * np.sqrt(np.diag(cov)), rtol=1e-12)
    assert low[-1] > 0 and mass not in d["unpinned"]  # a real effect: told from its absence
    # The covariance is sigma^2 (J^T J)^-1 with J the derivative of ln|Z| of the extended model at the estimate:
    # central differences of the Krylov FRF (steps of 1e-4 of each parameter's scale) as the reference.
    freqs = np.unique(pd.read_parquet(root / "closure" / "residual_after.parquet")["frequency_hz"])
    effect = {e.kind: e for e in build_library(benchmark_model, ["point_mass"])}["point_mass"]
    location = on_disk["effects"][0]["location"]

    def log_amp(theta):
        applied = [Applied(effect, location, theta[6:])]
        return np.log(np.abs(extended_frf(benchmark_model, theta[:6], freqs, applied))).ravel()

    steps = 1e-4 * np.r_[np.full(6, 0.1), effect.scale_at(location)]
    J = np.column_stack([(log_amp(est + h * e) - log_amp(est - h * e)) / (2 * h) for h, e in zip(steps, np.eye(7))])
    reference = 0.005**2 * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), np.sqrt(np.diag(reference)), rtol=1e-3)
    assert on_disk["interval_cost"]["jacobians"] <= 3 and "exact" in on_disk["interval_cost"]["columns"]
    out = io.StringIO()
    dg.print_closure(on_disk, file=out)
    assert "95 % intervals after the closure" in out.getvalue() and mass in out.getvalue()


def test_closure_intervals_cover_every_effect_of_a_forward_selection(benchmark_model):
    """Issues 18 + 19: the intervals of a two-effect final fit (as forward selection leaves it: an earlier
    effect refitted with the new one) are named as closure.json's parameters_after and hold the truth.

    Noise-free data of the true alpha, a 0.12 kg mass and a 4e5 N/m spring (direct solver); the fit starts
    off (mass 0.06 kg, spring 2e5 N/m) and ends at the truth; the intervals at 0.5 % noise must hold it and
    tell both effects from their absence.
    """
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.closure.fits import fit_update
    from fe_core.closure.effects import Applied, build_library, extended_frf
    from tasks.closure.summary import _params
    from tasks.closure.intervals import closure_interval_fields

    library = {e.kind: e for e in build_library(benchmark_model, ["point_mass", "grounded_spring"])}
    pm, gs = library["point_mass"], library["grounded_spring"]
    freqs = np.linspace(20, 400, 40)
    truth = [Applied(pm, "node 337", np.array([0.12])), Applied(gs, "node 919", np.array([4e5]))]
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, freqs, truth, method="direct"))
    final = fit_update(benchmark_model, freqs, u, ALPHA_ACTUAL, gs, "node 919", [2e5],
                       prior=[Applied(pm, "node 337", np.array([0.06]))], max_evaluations=300)
    names = list(_params(final, library))
    assert names[6:] == ["point_mass@node 337.mass", "grounded_spring@node 919.k"]
    fields = closure_interval_fields(benchmark_model, freqs, u, final, names, 0.005, (-0.95, 1.0))
    assert list(fields["intervals"]) == names
    theta = np.r_[ALPHA_ACTUAL, 0.12, 4e5]
    for name, t in zip(names, theta):
        lo, hi = fields["intervals"][name]
        assert lo <= t <= hi, (name, lo, t, hi)
    assert fields["intervals"]["point_mass@node 337.mass"][0] > 0
    assert fields["intervals"]["grounded_spring@node 919.k"][0] > 0
    assert not any(n in fields["interval_details"]["unpinned"] for n in names[6:])


@pytest.mark.slow
def test_a_second_diagnosis_reads_every_step_back(diagnosed):
    root, summary, again = diagnosed
    strip = {"wall_seconds"}

    assert {k: v for k, v in again.items() if k not in strip} == {k: v for k, v in summary.items() if k not in strip}


@pytest.mark.slow
def test_a_closure_killed_during_its_checks_redoes_only_the_missing_ones(diagnosed, tmp_path, prefect_harness):
    root, summary, _ = diagnosed
    closure = root / "closure"
    checks = sorted((closure / "step=check").glob("check=*.parquet"))
    assert len(checks) >= 2
    # What a kill during the check stage leaves: some per-candidate files, no record, no table.
    (closure / "step=check" / "_step.json").unlink()
    (closure / "step=check" / "checks.parquet").unlink()
    checks[-1].unlink()
    kept = {p: p.stat().st_mtime_ns for p in checks[:-1]}
    resumed = dg.diagnose("pm", root.parent, **OPTIONS)
    assert {p: p.stat().st_mtime_ns for p in checks[:-1]} == kept
    assert checks[-1].exists()
    assert resumed["effect"]["location"] == summary["effect"]["location"]
    assert resumed["error_after"] == pytest.approx(summary["error_after"], rel=1e-6)


@pytest.mark.slow
def test_the_decision_rebuilds_the_baseline_and_the_checks_from_their_stored_amplitudes(diagnosed, tmp_path,
                                                                                       monkeypatch, prefect_harness):
    """The baseline and every check store their model amplitudes; the decision rebuilds their fits from them
    without an FE solve each (at 500k DOFs one takes 1.5-2 min; a far-off case has 38 checks), to the decision of
    the diagnosis that stored them."""
    import shutil

    from tasks.closure import store as closure_store

    root, summary, _ = diagnosed
    copy = tmp_path / "runs" / "pm"
    shutil.copytree(root, copy)
    for name in ("_step.json", "candidates.parquet", "residual_after.parquet"):
        (copy / "closure" / "step=decide" / name).unlink(missing_ok=True)
    (copy / "closure" / "closure.json").unlink()
    solved = []
    real = closure_store.extended_frf
    monkeypatch.setattr(closure_store, "extended_frf", lambda *a, **k: solved.append(1) or real(*a, **k))
    decided = dg.diagnose("pm", copy.parent, **OPTIONS)
    assert solved == []
    assert decided["effect"]["location"] == summary["effect"]["location"]
    assert decided["effect"]["value"] == pytest.approx(summary["effect"]["value"], rel=1e-9)
    assert decided["error_after"] == pytest.approx(summary["error_after"], rel=1e-6)


def test_diagnosis_of_a_missing_or_unfinished_run_exits_2_naming_the_file(tmp_path, capsys):
    assert dg.main(["--run-id", "nothing", "--runs-dir", str(tmp_path)]) == 2
    assert "nothing/summary.json: no summary.json" in capsys.readouterr().err
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "summary.json").write_text(json.dumps({"parameters": {"alpha_1": 0.0}}))
    assert dg.main(["--run-id", "half", "--runs-dir", str(tmp_path)]) == 2
    assert "half/manifest.json: no manifest.json" in capsys.readouterr().err
    # a modal run (here its record from before the summary's schema) has its closure in its own summary
    (tmp_path / "modal").mkdir()
    (tmp_path / "modal" / "summary.json").write_text(json.dumps(
        {"kind": "modal update", "parameters": {"alpha_1": {"value": 0.1, "sd": 0.01, "lower95": 0.08, "upper95": 0.12}}}))
    assert dg.main(["--run-id", "modal", "--runs-dir", str(tmp_path)]) == 2
    assert "modal/summary.json: run 'modal' is a modal update" in capsys.readouterr().err


def test_unknown_effects_and_bad_noise_are_refused(tmp_path, capsys):
    run = tmp_path / "r"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"parameters": {f"alpha_{i}": 0.0 for i in range(1, 7)}}))
    (run / "manifest.json").write_text(json.dumps({"config": {"measured": str(DATA / "clean-seed0.csv")}}))
    assert dg.main(["--run-id", "r", "--runs-dir", str(tmp_path), "--effects", "point_mass,gremlin"]) == 2
    assert "unknown effect(s) gremlin" in capsys.readouterr().err
    assert dg.main(["--run-id", "r", "--runs-dir", str(tmp_path), "--noise", "-0.1"]) == 2
    assert "--noise must be positive" in capsys.readouterr().err


def test_update_help_lists_the_close_loop_options(capsys):
    with pytest.raises(SystemExit):
        update.main(["--help"])
    out = capsys.readouterr().out
    for flag in ("--close-loop", "--noise", "--effects", "--restarts", "--closure-emulator"):
        assert flag in out


@pytest.mark.slow
def test_a_model_given_as_matrices_is_diagnosed_and_effects_needing_a_mesh_are_refused(reduced_config,
                                                                                      prefect_harness, capsys):
    """Issue 15: the closure on a model file without a mesh (scikit-fem's cantilever as matrices, its own
    FRF with 0.5 % noise): nodal effects from the DOF table, no patch, and the verdict noise."""
    from fe_core.closure.decisions import VERDICTS

    example = REPO / "data" / "examples" / "cantilever_matrices"
    config = reduced_config.replace(run_id="cantilever", model=str(example / "model.toml"),
                                    measured=str(example / "measured.csv"), max_iterations=2, max_fe_evaluations=19,
                                    polish_max_fe=7)
    update.update_flow(config)
    runs = Path(config.runs_dir)
    assert dg.main(["--run-id", "cantilever", "--runs-dir", str(runs), "--effects", "point_mass,patch"]) == 2
    err = capsys.readouterr().err
    assert "'patch' does not apply to the model" in err and "needs a mesh" in err
    assert not (runs / "cantilever" / "closure").exists()  # refused before any work
    summary = dg.diagnose("cantilever", runs, noise=0.005)
    assert summary["verdict"] in VERDICTS and summary["verdict"] == "noise" and summary["effects"] == []
    truth = json.loads((example / "truth.json").read_text())["alpha"]
    before = [summary["parameters_before"][f"alpha_{i}"] for i in range(1, 5)]
    assert np.max(np.abs(np.array(before) - truth)) < 0.01  # the alpha-only refit is the truth
    kinds = {c["type"] for c in summary["candidates"]}
    assert "patch" not in kinds and "joint_band" not in kinds
    table = np.loadtxt(example / "dofs.csv", delimiter=",", skiprows=1, dtype=str)
    nodes = {int(n) for n in table[:, 0]}
    assert all(int(c["location"].split()[1]) in nodes for c in summary["candidates"] if c["type"] == "point_mass")


@pytest.mark.slow
def test_a_closure_run_is_reported_and_its_stages_rerun(diagnosed, capsys):
    """The tools around a run know a run with a closure: the report draws the closure beside the update, and a
    stage of the update reruns from its stored inputs into a folder of its own."""
    from flows import report
    from tasks.runstore import RunStore

    root, summary, _ = diagnosed
    assert report.main(["--run-id", root.name, "--runs-dir", str(root.parent)]) == 0
    page = Path(capsys.readouterr().out.strip().splitlines()[-1])
    text = page.read_text()
    assert "Close the loop" in text and f"Verdict: {summary['verdict']}" in text
    for png in ("closure_residuals.png", "closure_candidates.png", "closure_frf.png", "frf_overview.png"):
        assert (page.parent / png).stat().st_size > 5000
    store = RunStore(root)
    original = store.read_table(1, "train", "hyperparameters")
    out = update.rerun_stage(root, 1, "train", trainer="sao")
    assert store.stage_info(1, out.name.split("=", 1)[1])["trainer"] == "sao"
    pd.testing.assert_frame_equal(store.read_table(1, "train", "hyperparameters"), original)


@pytest.mark.parametrize("update_minutes, flag, limit", [(3.0, [], 11.5), (4.97, [], 9.5), (11.0, [], 5.0),
                                                         (11.0, ["--closure-minutes", "20"], 20.0)])
def test_close_loop_gives_its_closure_what_is_left_of_the_commands_fifteen_minutes(tmp_path, monkeypatch, capsys,
                                                                                   update_minutes, flag, limit):
    """Issue 40's 15 minutes per case: the update's time and half a minute for the command's own start and end
    come off the closure's limit, rounded down to a tenth (at least 5 min are left to it), unless --closure-minutes
    says otherwise. The update and the closure are stand-ins that only pass time;
    the model and data are read for real (the cantilever as matrices)."""
    from types import SimpleNamespace

    clock = [1000.0]
    monkeypatch.setattr(update, "time", SimpleNamespace(monotonic=lambda: clock[0]))

    def an_update(config, problem):
        clock[0] += 60.0 * update_minutes
        return {}

    seen = {}
    monkeypatch.setattr(update, "update_flow", an_update)
    monkeypatch.setattr(update, "print_summary", lambda summary: None)
    monkeypatch.setattr(dg, "diagnose", lambda *a, **k: seen.update(k) or {})
    monkeypatch.setattr(dg, "print_closure", lambda closure: None)
    matrices = REPO / "data" / "examples" / "cantilever_matrices"
    code = update.main(["--model", str(matrices / "model.toml"), "--measured", str(matrices / "measured.csv"),
                        "--runs-dir", str(tmp_path), "--run-id", "timed", "--close-loop", *flag])
    out = capsys.readouterr().out
    assert code == 0 and seen["max_minutes"] == pytest.approx(limit)
    assert (f"closure: time limit {limit:g} min" in out) == (not flag), out
