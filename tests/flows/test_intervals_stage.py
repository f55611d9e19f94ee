"""The intervals stage after the polish: summary.json fields, the printed +/- column, resume and --noise."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from fe_core.benchmark import ALPHA_ACTUAL
from flows import update
from flows.summary import LEAST_SQUARES_SOURCE, report_least_squares_optimum, summary_interval_fields
from flows.config import ConfigError, UpdateConfig, load_config
from tasks.intervals import INTERVALS_STAGE
from tasks.runstore import RunStore


def test_summary_has_intervals_covariance_and_method_and_a_changed_noise_reruns_them(reduced_config,
                                                                                          prefect_harness,
                                                                                          check_summary):
    # posterior_fe = 0: the Laplace intervals whatever the check would say (the sampled path: the next test).
    # emulate = "errors": the paper's emulation ends this reduced run far from the optimum, which the sampled
    # path below needs (the modal one ends near enough for the linearity check to pass).
    config = reduced_config.replace(intervals=True, noise=0.002, true_parameters=ALPHA_ACTUAL.tolist(),
                                    posterior_fe=0, emulate="errors")
    summary = update.update_flow(config)
    root = Path(config.runs_dir) / config.run_id
    on_disk = json.loads((root / "summary.json").read_text())
    check_summary(on_disk)  # the one shape, with its intervals
    names = list(summary["parameters"])
    for key in ("intervals", "covariance", "interval_method", "noise_sigma"):
        assert on_disk[key] == summary[key]
    assert summary["interval_method"] == "laplace" and summary["noise_sigma"] == 0.002
    cov = np.array(summary["covariance"], float)
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    est = np.array([summary["interval_details"]["estimate"][n] for n in names])
    low, high, sd = np.array([[summary["intervals"][n][k] for k in ("lower95", "upper95", "sd")] for n in names]).T
    z = stats.norm.ppf(0.975)  # noise given: normal quantile
    np.testing.assert_allclose(sd, np.sqrt(np.diag(cov)), rtol=1e-12)
    np.testing.assert_allclose(low, est - z * np.sqrt(np.diag(cov)), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(high, est + z * np.sqrt(np.diag(cov)), rtol=1e-12, atol=1e-15)
    cost = summary["interval_cost"]
    # the Jacobians bring their FRFs; the one FE run is the run's own error measure at the optimum
    assert 1 <= cost["jacobians"] <= 3 and cost["fe_runs"] == 1
    # the time in FE runs of this update: a Krylov Jacobian costs a few (CPU-time ratio ~2 when idle; wall
    # time on busy cores scatters, hence the loose bound)
    assert 0 < cost["fe_run_equivalents"] < 20 * cost["jacobians"] and cost["fe_run_seconds"] > 0
    assert cost["share_of_update_fe_runs"] == pytest.approx(cost["fe_run_equivalents"] / summary["fe_evaluations"],
                                                            rel=0.01)  # both rounded in the summary
    assert set(summary["intervals_contain_truth"]) == set(names)
    # the stored table agrees with the summary
    table = RunStore(root).read_table(summary["iterations"], INTERVALS_STAGE)
    np.testing.assert_allclose(table[[f"cov_{n}" for n in names]].to_numpy(), cov, rtol=1e-12)
    out = io.StringIO()
    update.print_summary(summary, file=out)
    text = out.getvalue()
    # This reduced run ends far from the optimum (tens of % per channel): the residual there is structure, so the
    # intervals are conditional, not 95 % ones (tests/flows/test_conditional_intervals.py has the full story).
    assert summary["residual_check"]["structured"] and summary["interval_status"] == "conditional"
    assert "+/- (cond.)" in text and "laplace" in text and "noise 0.2 % (given, normal" in text
    assert "exact Jacobian" in text and "% of the update's" in text

    # resume: read back; with another noise level: recomputed from the same start, widths scale with the noise
    stage = RunStore(root).stage_dir(summary["iterations"], INTERVALS_STAGE) / f"{INTERVALS_STAGE}.parquet"
    mtime = stage.stat().st_mtime_ns
    again = update.update_flow(config)
    assert again["intervals"] == summary["intervals"] and stage.stat().st_mtime_ns == mtime
    # another noise level is another run's input, refused on resume; the intervals stage reruns with it
    with pytest.raises(ConfigError, match=r"setting noise \(0.002 then, 0.004 now\).*--stage check --noise"):
        update.update_flow(config.replace(noise=0.004))
    rerun = update.rerun_stage(root, summary["iterations"], INTERVALS_STAGE, noise=0.004)
    info = RunStore(root).stage_info(summary["iterations"], rerun.name.removeprefix("stage="))
    assert info["noise_sigma"] == 0.004
    np.testing.assert_allclose(np.array(info["covariance"]), 4 * cov, rtol=1e-9)

    # The sampled path on the same run, rerun at the higher noise with posterior_fe = 40: the reduced run ends
    # far from the optimum, flagged parameters fail the linearity check, 40 FE runs sample the posterior.
    rerun = update.rerun_stage(root, summary["iterations"], INTERVALS_STAGE, noise=0.004, posterior_fe=40)
    sampled = RunStore(root).stage_info(summary["iterations"], rerun.name.removeprefix("stage="))
    d = sampled["interval_details"]
    assert sampled["interval_method"] == "importance sampling" and d["method_reason"].startswith("importance")
    assert d["posterior"]["fe_runs"] == 40 and d["linearity"]["poor"]
    assert sampled["interval_cost"]["posterior_fe_runs"] == 40
    assert sampled["interval_cost"]["fe_runs"] == 40 + d["linearity"]["fe_runs"] + 1  # + the error at the optimum
    low, high = np.array([sampled["intervals"][n] for n in names]).T
    assert np.all(low >= -1.0) and np.all(high <= 1.0) and np.all(low <= high)  # on the search box
    assert d["laplace"]["intervals"] == info["intervals"]  # the Laplace ones kept beside
    out = io.StringIO()
    update.print_summary({**summary, **summary_interval_fields(sampled)}, file=out)
    assert "importance sampling of the posterior" in out.getvalue() and "why: importance" in out.getvalue()


def test_noise_key_is_validated_and_reaches_the_config(tmp_path):
    assert load_config(None, noise=0.005).noise == 0.005
    assert UpdateConfig().noise is None and UpdateConfig().intervals
    with pytest.raises(ConfigError, match="command line: key 'noise'"):
        load_config(None, noise=0.0)
    bad = tmp_path / "bad.toml"
    bad.write_text('noise = "1 %"\n')
    with pytest.raises(ConfigError, match="bad.toml: key 'noise' must be int or float"):
        load_config(bad)
    assert UpdateConfig().posterior_fe == 400 and load_config(None, posterior_fe=0).posterior_fe == 0
    with pytest.raises(ConfigError, match="command line: key 'posterior_fe'"):
        load_config(None, posterior_fe=-1)
    bad.write_text("noise = 1.5\n")
    with pytest.raises(ConfigError, match=r"bad.toml: key 'noise': must be a relative amplitude noise in \(0, 1\)"):
        load_config(bad)


def test_report_section_draws_marginals_and_correlations_and_repeats_the_flags(tmp_path, rng):
    from types import SimpleNamespace

    from fe_core.inference.laplace import laplace_intervals
    from tasks.report.sections import intervals_section

    X = rng.normal(size=(40, 3))
    X[:, 2] = 0.02 * X[:, 2]  # alpha_3 barely seen: a wide interval
    iv = laplace_intervals(0.01 * rng.normal(size=40), X, [0.1, 0.999, -0.2], noise=0.01, lower=-0.999, upper=1.0)
    summary = {**summary_interval_fields(iv.to_summary()), "interval_cost": {"fe_runs": 1, "jacobians": 1}}
    data = SimpleNamespace(summary=summary, true_parameters=np.array([0.1, 0.999, -0.2]), config={})
    section = intervals_section(data, tmp_path)
    assert (tmp_path / "intervals.png").stat().st_size > 10_000
    table = section.tables[0][1]
    assert list(table["contains truth"]) == [True, True, True]
    assert any("alpha_3 is not pinned down" in p for p in section.paragraphs)
    assert any("alpha_2's 95% interval" in p and "crosses a bound" in p for p in section.paragraphs)
    assert intervals_section(SimpleNamespace(summary={"parameters": {}}, config={}), tmp_path) is None

    # A sampled posterior: its weighted samples are drawn from the stage's posterior.parquet.
    import pandas as pd

    from fe_core.inference.posterior import LinearityCheck, Posterior, sampled_summary

    names = iv.names
    X = iv.estimate + 0.01 * rng.normal(size=(200, 3))
    w = np.full(200, 1 / 200)
    post = Posterior(names=names, mean=X.mean(0), covariance=np.cov(X.T), low=X.min(0), high=X.max(0), level=0.95,
                     samples=X, weights=w, ess=200.0, fe_runs=200, outside_box=3)
    check = LinearityCheck(names=names, checked=np.array([False, True, False]), ratio=np.full((3, 2), np.nan),
                           outside=np.array([[False, False], [False, True], [False, False]]), tolerance=0.25,
                           fe_runs=1)
    sampled = {**summary_interval_fields(sampled_summary(iv, check, post, 200)),
               "interval_cost": {"fe_runs": 201, "jacobians": 1},
               "iterations": 2}
    folder = tmp_path / "run" / "iteration=2" / "stage=intervals"
    folder.mkdir(parents=True)
    pd.DataFrame(X, columns=names).assign(weight=w).to_parquet(folder / "posterior.parquet")
    out = tmp_path / "sampled"
    out.mkdir()
    section = intervals_section(SimpleNamespace(summary=sampled, true_parameters=None, config={},
                                                root=tmp_path / "run"), out)
    assert (out / "intervals.png").stat().st_size > 10_000
    assert section.paragraphs[0].startswith("Importance sampling of the posterior")
    assert any(p.startswith("Why: importance sampling: alpha_2's interval crosses") for p in section.paragraphs)


def test_the_least_squares_optimum_is_reported_and_the_lowest_error_run_kept_beside_it():
    names = ["alpha_1", "alpha_2"]
    summary = {"parameters": {"alpha_1": 0.10, "alpha_2": -0.20}, "overall_error": 0.0071, "best_sample_id": 42,
               "per_sensor_error": {"sensor_1": 0.006, "sensor_3": 0.008},
               "parameter_errors": {"alpha_1": 0.02, "alpha_2": 0.01},
               "interval_details": {"estimate": {"alpha_1": 0.11, "alpha_2": -0.19}},
               "estimate_errors": {"overall_error": 0.0072, "per_sensor_error": [0.0065, 0.0079], "at_optimum": True}}
    out = report_least_squares_optimum(summary, [1, 3], truth=[0.12, -0.21])
    assert out["parameters"] == {"alpha_1": 0.11, "alpha_2": -0.19}
    assert out["parameters_source"] == LEAST_SQUARES_SOURCE and "estimate_errors" not in out
    assert out["overall_error"] == 0.0072 and out["per_sensor_error"] == {"sensor_1": 0.0065, "sensor_3": 0.0079}
    assert out["parameter_errors"] == pytest.approx({"alpha_1": 0.01, "alpha_2": 0.02})
    low = out["lowest_error"]
    assert low["parameters"] == summary["parameters"] and low["overall_error"] == 0.0071 and low["sample_id"] == 42
    assert low["parameter_errors"] == summary["parameter_errors"] and out["best_sample_id"] == 42
    text = io.StringIO()
    update.print_summary({**out, "run_folder": "x", "strategy": "adaptive", "trainer": "gradient", "converged": True,
                          "iterations": 2, "fe_evaluations": 100, "wall_seconds": 1.0}, file=text)
    assert "at the reported parameters, the least-squares optimum" in text.getvalue() and "lowest 6b" in text.getvalue()
    # Gauss-Newton not settled: the lowest-error run stays, and the summary says why
    kept = report_least_squares_optimum({**summary, "estimate_errors": {**summary["estimate_errors"],
                                                                               "at_optimum": False}}, [1, 3])
    assert kept["parameters"] == summary["parameters"] and "lowest_error" not in kept
    assert "did not settle" in kept["parameters_source"] and names == list(kept["parameters"])
