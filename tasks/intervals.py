"""The intervals stage: 95 % intervals and the covariance of the updated parameters.

After the polish, :func:`fe_core.inference.intervals.parameter_intervals` takes
Gauss-Newton steps with the exact Jacobian (Krylov, with its FRF) from the run's best
parameters to the least-squares optimum of the log-amplitude residual and
computes the Laplace intervals there (noise from ``config.noise`` or
estimated from the residual). Where the Laplace approximation flags a
parameter (an interval wider than the threshold or crossing the search box),
the linearity check of :mod:`fe_core.inference.posterior` looks along it (two FE runs
each); if the check fails, a posterior sampled on the FE model (importance
sampling, ``config.posterior_fe`` FE runs) gives the intervals instead, and
the summary says which method was used and why
(``interval_details.method_reason``). Written to
``iteration=<K>/stage=intervals/intervals.parquet`` (one row per parameter:
estimate, interval, standard deviation, the covariance row, the Laplace
interval; ``posterior.parquet``: the sampled points and their weights, when
sampled) with the summary fields in the stage record; a resumed run reads
them back unless ``noise`` or ``posterior_fe`` changed (the settings a resume
may change that the intervals depend on).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.inference.intervals import parameter_intervals
from fe_core.solvers import reduced_basis
from fe_core.inference.residual import analyse_residual
from fe_core.inference.posterior import importance_posterior, laplace_reason, linearity_check, sampled_summary
from tasks.common import beating
from tasks.fe_runs import solver_threads
from tasks.jacobian_memo import last_jacobian
from tasks.common import logger as run_logger
from tasks.problem import black_box
from tasks.runstore import RunStore

__all__ = ["INTERVALS_STAGE", "POSTERIOR_TABLE", "intervals_task"]

INTERVALS_STAGE = "intervals"
#: The sampled posterior's FE-evaluated points and normalised weights (when it was used).
POSTERIOR_TABLE = "posterior"


@task(name="intervals", task_run_name="iteration-{iteration}-intervals", cache_policy=NO_CACHE)
@beating("intervals (Gauss-Newton to the least-squares optimum, checks, the sampled posterior)")
def intervals_task(root: str, problem, config, iteration: int, start, output_stage: str = INTERVALS_STAGE,
                   not_sampled: str = "") -> dict:
    """Intervals near ``start`` (shape (n_parameters,), the run's best parameters); returns the stage record's info.

    The info holds the ``summary.json`` fields (``intervals``, ``covariance``,
    ``interval_method``, ``noise_sigma``, ``interval_details``) and the cost
    (``interval_cost``: Jacobians, FE runs besides them, seconds; the flow adds the
    cost in FE runs of the update).

    The data (``problem.data``): the log amplitudes of its channels on the lines where every channel is kept
    (coherence), through the model seen with the channels' one reference as its load; the phase of complex
    data is not used here (the intervals' error model is the relative amplitude noise). Data with several
    references (roving hammer, MIMO) stack their channels in one residual (the same relative amplitude noise on
    every channel; one Krylov space per point carries every reference's load). ``output_stage``: another
    folder (a rerun). ``not_sampled``: why the posterior is not sampled even where the linearity check would ask
    for it (the Laplace intervals are reported with that reason); empty: sampled as ``config.posterior_fe`` says.
    """
    store = RunStore(root)
    logger = run_logger()
    settings = {"noise_config": config.noise, "posterior_fe_config": 0 if not_sampled else config.posterior_fe}
    if store.is_finished(iteration, output_stage):
        info = store.stage_info(iteration, output_stage)
        old = {k: info.get(k) for k in settings}  # a record from before the sampled posterior: computed again
        if old == settings:
            logger.info("iteration %d, stage intervals: finished earlier, read back", iteration)
            return info
        logger.info("iteration %d, stage intervals: settings changed from %s to %s, computed again", iteration,
                    old, settings)
    data, full_model = problem.data, problem.model
    reduced_basis.forget(full_model)  # a large model's global basis (n x r doubles): the intervals are full order
    try:
        model, channels = data.single_reference_model(full_model), None
    except ValueError:  # several references (roving hammer, MIMO): the channels stacked in one residual
        model, channels = full_model, data.channels
        logger.info("iteration %d, stage intervals: %d references stacked in one error model", iteration,
                    np.unique(data.references).size)
    lines = data.complete_lines
    freqs_hz, measured_amplitude = data.frequencies_hz[lines], data.amplitude[lines]
    lower, upper = problem.solver_box
    t0, c0 = time.perf_counter(), time.process_time()
    noise = data.noise_spec(config.noise, lines)  # the configured level, the measured noise, or estimated
    with solver_threads(problem, config):  # a large model: PARDISO on the run's cores (nothing else runs now)
        known = last_jacobian(full_model, start, freqs_hz, data.channels)  # the local phase's confirmed centre
        if known is not None:
            logger.info("iteration %d, stage intervals: the Jacobian at the start from the local phase's last FE run",
                        iteration)
        refined = parameter_intervals(model, freqs_hz, measured_amplitude, np.asarray(start, float), lower, upper,
                                      noise=noise, channels=channels, known=known)
        jacobian_seconds = time.perf_counter() - t0
        iv = refined.intervals
        fields, check, post = _check_and_sample(model, freqs_hz, measured_amplitude, refined, lower, upper,
                                                settings["posterior_fe_config"], config.seed, channels)
    if not_sampled:
        fields["interval_details"]["method_reason"] = f"laplace, not sampled: {not_sampled}"
    if refined.noise_model is not None:  # weighted by the noise per line and channel: say which
        fields["noise_model"] = refined.noise_model.to_dict()
        fields["interval_details"]["noise"] = refined.noise_model.describe()
    if channels is not None:
        fields["interval_details"]["references"] = int(np.unique(data.references).size)
    unweighted = refined.residual if refined.weights is None else refined.residual * refined.weights
    tested = refined.noise_model if refined.noise_model is not None and refined.noise_model.source != "estimated" \
        else (noise if refined.noise_model is not None else config.noise)  # an estimated model: estimated again
    fields["residual_check"] = residual_check(unweighted, freqs_hz, len(model.parameter_names), tested)
    seconds = time.perf_counter() - t0
    cols = model.parameter_names
    reported = np.array(fields["covariance"], float)
    low, high = np.array([fields["intervals"][c] for c in cols], dtype=float).T
    table = pd.DataFrame({"parameter": cols, "start": refined.start, "estimate": iv.estimate, "low": low,
                          "high": high, "std": np.sqrt(np.diag(reported)), "unpinned": iv.unpinned,
                          "near_bound": iv.near_bound, "laplace_low": iv.low, "laplace_high": iv.high,
                          "laplace_std": iv.std})
    for j, c in enumerate(cols):
        table[f"cov_{c}"] = reported[:, j]
    store.write_table(iteration, output_stage, INTERVALS_STAGE, table)
    names = [INTERVALS_STAGE]
    if post is not None:  # the weighted samples, for the report's marginal posteriors
        samples = pd.DataFrame(post.samples, columns=cols).assign(weight=post.weights)
        store.write_table(iteration, output_stage, POSTERIOR_TABLE, samples)
        names.append(POSTERIOR_TABLE)
    fe_runs = refined.fe_runs + (check.fe_runs if check is not None else 0) + (post.fe_runs if post else 0)
    # The run's own error measure (its lines, coherence mask and residual kind, which the log amplitudes of the
    # complete lines are not): one FE run at the optimum, unless one was made there already (no step was taken, or a
    # chord step's FRF on every line).
    kept = last_jacobian(full_model, iv.estimate, data.frequencies_hz, data.channels)
    Z = kept[0] if kept is not None else refined.frf_at_estimate if np.all(lines) else None
    with solver_threads(problem, config):
        rel = data.residuals(Z if Z is not None else
                             full_model.parameter_frf(iv.estimate, data.frequencies_hz, data.channels))
    per_channel = data.channel_errors(rel)
    fe_runs += Z is None
    fields["estimate_errors"] = {"overall_error": float(np.mean(np.abs(rel))),
                                 "per_sensor_error": np.asarray(per_channel, float).tolist(),
                                 "at_optimum": refined.at_optimum}
    info = {**fields, **settings,
            "interval_cost": {"fe_runs": fe_runs, "jacobians": refined.jacobians, "seconds": round(seconds, 3),
                              "cpu_seconds": round(time.process_time() - c0, 3),
                              "jacobian_seconds": round(jacobian_seconds, 3), "at_optimum": refined.at_optimum,
                              "last_step_in_std": (refined.last_step_in_std if np.isfinite(refined.last_step_in_std)
                                                   else None),
                              "first_order_frfs": refined.first_order_frfs,  # chord steps' FRFs expanded
                              "check_fe_runs": check.fe_runs if check is not None else 0,
                              "posterior_fe_runs": post.fe_runs if post else 0}}
    if black_box(full_model):  # each Jacobian is m + 1 solver runs (in threads, one solver process each)
        info["interval_cost"].update(jacobian_kind="forward-difference",
                                     solver_runs=refined.jacobians * (len(cols) + 1) + fe_runs)
    store.finish(iteration, output_stage, names, info)
    noise_text = (f"the noise per line and channel, {refined.noise_model.describe()}" if refined.noise_model is not None
                  else f"{iv.noise_source} noise {100 * iv.noise_sigma:.3g} %")
    logger.info("iteration %d, stage intervals: %s; %s, %d exact Jacobians with their FRF and %d FE runs (%.2f s)",
                iteration, fields["interval_method"], noise_text, refined.jacobians, fe_runs, seconds)
    for line in fields["interval_details"]["flags"]:
        logger.warning(line)
    return store.stage_info(iteration, output_stage)


def residual_check(residual, freqs_hz, n_fitted: int, noise) -> dict | None:
    """Noise or structure in the log residual at the intervals' estimate (:func:`analyse_residual`, 1 % level).

    The intervals assume the model explains the data up to noise; structure means they are conditional on a
    model that does not (``flows.summary.interval_status``). None when no noise level can be estimated.
    """
    r = np.asarray(residual, float).reshape(len(freqs_hz), -1)
    try:
        a = analyse_residual(r, freqs_hz, n_fitted, noise)
    except ValueError:
        return None
    return {"structured": a.structured, "rms": a.rms, "sigma": a.sigma, "sigma_source": a.sigma_source,
            "p_chi2": a.p_chi2, "text": a.summary()}


def _check_and_sample(model, freqs_hz, measured_amplitude, refined, lower, upper, posterior_fe: int, seed=0,
                      channels=None):
    """The Laplace fields, or the sampled posterior's where the linearity check fails; also (check, posterior).

    The check (two FE runs per parameter) looks at the parameters the Laplace flags (an interval wider
    than the threshold or crossing the box) and only when sampling is allowed (``posterior_fe`` > 0).
    """
    iv = refined.intervals
    fields = iv.to_summary()
    flagged = iv.unpinned | iv.near_bound
    check = post = None
    if posterior_fe > 0 and flagged.any() and np.isfinite(iv.covariance).all():
        log_u = np.log(np.asarray(measured_amplitude, float)).ravel()
        weights = 1.0 if refined.weights is None else refined.weights  # as the intervals saw it

        def residual(alpha):
            return (np.log(np.abs(model.parameter_frf(alpha, freqs_hz, channels))).ravel() - log_u) / weights

        check = linearity_check(residual, iv, refined.residual, lower, upper, which=flagged)
        if check.poor.any():
            try:
                post = importance_posterior(residual, iv, lower, upper, np.random.default_rng([seed, 19]),
                                            budget=posterior_fe)
            except (ValueError, np.linalg.LinAlgError) as exc:  # keep the Laplace intervals, say why
                fields["interval_details"]["method_reason"] = (f"laplace, though its check failed "
                                                               f"({'; '.join(check.reasons())}): sampling failed: {exc}")
                fields["interval_details"]["linearity"] = check.to_dict()
                return fields, check, None
            return sampled_summary(iv, check, post, posterior_fe), check, post
    fields["interval_details"]["method_reason"] = laplace_reason(iv, check)
    if check is not None:
        fields["interval_details"]["linearity"] = check.to_dict()
    elif flagged.any():
        fields["interval_details"]["method_reason"] = (
            "laplace: posterior_fe = 0 (no sampling)" if posterior_fe == 0 else
            "laplace: a parameter the data do not see (infinite variance) cannot be sampled")
    return fields, check, post


def cost_against_update(summary: dict) -> str | None:
    """The intervals' time against the update's, in words, or None when not measured (printed summary and report).

    E.g. ``"0.09 s, the time of 6.4 FE runs: 13.5 % of the update's 47.5 FE-run equivalents"``; the update's
    count is its FE-run equivalents where FE runs carried Jacobians (the hybrid), else its FE runs.
    """
    cost = summary.get("interval_cost", {})
    if "fe_run_equivalents" not in cost:
        return None
    spent = (f"{summary['fe_equivalents']:g} FE-run equivalents" if "fe_equivalents" in summary else
             f"{summary.get('fe_evaluations', '?')} FE runs")
    return (f"{cost['seconds']:.2f} s, the time of {cost['fe_run_equivalents']:.1f} FE runs: "
            f"{100 * cost['share_of_update_fe_runs']:.1f} % of the update's {spent}")
