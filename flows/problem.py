"""A run's problem, resolved once before any work: the model, the measured data, the search box.

:func:`resolve` reads the measured file, hashes and reads the model file, matches the data to the model
(channels, lines, residual), checks the inputs, the settings of a resumed run and the disk, and returns the
:class:`tasks.problem.Problem` every stage of the run receives. Bad input raises
:class:`flows.config.ConfigError` or :class:`tasks.io.measured.MeasuredDataError` naming the file and the
key; nothing has been written into the run folder then.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from flows import preflight
from flows.config import ConfigError, UpdateConfig
from tasks import fe_backends
from tasks.io.measured import MeasuredDataError, read_measured
from tasks.problem import FE_FOLDER, Problem, black_box, read_model_ref, search_box
from tasks.update_data import UpdateData, update_data

__all__ = ["resolve", "stored_problem", "load_model", "prepare_data", "n_modes", "emulates_modes",
           "input_checksums", "RESUMABLE_CHANGES"]

#: Config keys that may change between a run and its resume.
# (where FE runs execute does not change their results: fe_backend, dask_address).
# (intervals and posterior_fe change only the intervals stage, computed again when they changed; noise shapes the
# hybrid's stored checks too, so a resume must keep it: `rerun --stage check --noise` shows another.)
RESUMABLE_CHANGES = {"n_jobs", "run_id", "runs_dir", "repeats", "min_free_mb", "fe_backend", "dask_address",
                     "intervals", "posterior_fe"}


#: The model cache's folder inside the runs folder (:mod:`fe_core.io.cache`).
MODEL_CACHE_FOLDER = ".model-cache"


def load_model(name: str, cache_root=None):
    """(model, :class:`tasks.problem.ModelRef`) of a run; a model file that cannot be used is a ConfigError
    naming the file and key. ``cache_root``: the model cache (a large model assembled once, mapped by every
    process: :func:`tasks.problem.read_model_ref`)."""
    from fe_core.io import ModelFileError

    try:
        return read_model_ref(name, cache_root)
    except ModelFileError as exc:
        raise ConfigError(str(exc)) from None


def prepare_data(config: UpdateConfig, measured, model) -> UpdateData:
    """The measured channels matched to the model, with the config's line selection and residual."""
    try:
        return update_data(measured, model, lines=config.lines, line_windows=config.line_windows,
                           resonance_widen=config.resonance_widen, min_coherence=config.min_coherence,
                           residuals=config.residuals)
    except MeasuredDataError:
        raise
    except ValueError as exc:
        raise ConfigError(f"config: key 'residuals': {exc}") from None


def emulates_modes(config: UpdateConfig) -> bool:
    """The strategy's FE runs give their lowest modes (the paper loop's ``emulate = "modes"``,
    :mod:`strategies.modal_emulation`), by its entry in :mod:`strategies.registry`."""
    from strategies import registry

    spec = registry.get(config.strategy)
    return bool(spec.modes(*spec.settings(config)))


def n_modes(model, freqs_hz) -> int:
    """Modes the FE runs give for the modal emulator: the nominal model's below ``BAND_FACTOR`` times the
    highest measured frequency, plus one (:func:`mrgp_core.modal_outputs.modes_to_emulate`)."""
    from mrgp_core.modal_outputs import BAND_FACTOR, modes_to_emulate

    highest = float(np.max(freqs_hz))
    alpha, gamma = model.factors(np.zeros(model.n_parameters))
    available = model.n_dofs - 1
    k = min(8, available)
    while True:  # past the band, so the gap after the last mode taken shows (a close pair is taken whole)
        freqs = model.natural_frequencies(alpha, k, gamma)
        if freqs[-1] >= 2 * BAND_FACTOR * highest or k == available:
            return modes_to_emulate(freqs, highest, available)
        k = min(2 * k, available)


def input_checksums(config: UpdateConfig, ref) -> dict:
    """SHA-256 of what a run reads: the model file with its mesh/matrices (``ref``), the measured file."""
    digest = hashlib.sha256(config.resolve(config.measured).read_bytes()).hexdigest()
    return {"model_checksum": ref.checksum, "measured_checksum": digest}


def resolve(config: UpdateConfig, measured=None) -> Problem:
    """The run's :class:`Problem`, after every check that needs no run folder: measured data, model, resume
    settings, disk, the Dask cluster. ``measured``: the file as the caller read it already
    (:func:`tasks.io.measured.read_measured` of ``config.measured``), else read here."""
    if measured is None:
        measured = read_measured(config.resolve(config.measured), averages=config.averages)
    cache_root = config.resolve(config.runs_dir) / MODEL_CACHE_FOLDER
    footprint = preflight.check_memory(config, cache_root)  # a model too big says so before it is assembled
    model, ref = load_model(config.model, cache_root)
    check_first_training(config, model.n_parameters)
    data = prepare_data(config, measured, model)
    preflight.check_inputs(config, data, model)
    root = config.resolve(config.runs_dir) / config.run_id
    inputs = input_checksums(config, ref)
    preflight.check_resume(config, root, RESUMABLE_CHANGES, inputs)
    required = config.min_free_mb or 2 * preflight.expected_output_mb(
        config, max(data.amplitude.size, data.n_values), model.n_parameters)
    preflight.check_disk(config, root, required)
    if config.fe_backend == "dask":  # an unreachable cluster is refused before any work, not in iteration 1
        try:
            fe_backends.check_dask(config.dask_address)
        except fe_backends.FEBackendError as exc:
            raise ConfigError(str(exc)) from None
    if black_box(model) and emulates_modes(config):
        raise ConfigError(f"config: key 'emulate': the paper loop's modal emulator needs each FE run's modes, which "
                          f"the black-box deck {config.model} does not give (route B): use --emulate errors")
    if black_box(model):  # its FE runs write their solver folders under the run folder
        ref = dataclasses.replace(ref, workdir=str(root / FE_FOLDER))
        model = model.with_workdir(ref.workdir)
    lower, upper = search_box(model, config.lower, config.upper)
    modes = n_modes(model, data.frequencies_hz) if emulates_modes(config) else 0
    return Problem(model, ref, data, lower, upper, modes, inputs, footprint and footprint.per_worker)


def check_first_training(config: UpdateConfig, n_parameters: int) -> None:
    """The paper's loop fits its first MRGP on the initial samples (``q``; the conventional baseline on all of its
    ``conventional_samples``), with the paper's linear mean ``[1, x]``: n_parameters + 1 columns, so it needs at least
    that many runs (:class:`mrgp_core.likelihood.ProfileLikelihood`). A ConfigError naming the key, before any FE
    run (a 150k-DOF run with ``-q 4`` on 9 parameters failed in its first training after 6 minutes)."""
    if config.strategy not in ("adaptive", "conventional"):
        return
    key = "conventional_samples" if config.strategy == "conventional" else "q"
    n = getattr(config, key)
    if (key == "q" and config.max_iterations < 2) or n >= n_parameters + 1:
        return  # one iteration only: the loop stops before it trains
    flag = "-q" if key == "q" else "--conventional-samples"
    raise ConfigError(f"config: key '{key}': the MRGP's linear mean [1, x] has {n_parameters + 1} columns for this "
                      f"model's {n_parameters} parameters, so its first fit needs at least {n_parameters + 1} runs; "
                      f"got {n} (raise {flag})")


def stored_problem(config: UpdateConfig, manifest: dict | None = None, where=None) -> Problem:
    """The problem of a stored run (its model, measured data and box, from its config), for the commands that
    work on a finished run (rerun, diagnose). With the run's ``manifest`` (at ``where``, its manifest.json), a
    model or measured file whose content changed since is refused (ConfigError)."""
    from pathlib import Path

    model, ref = load_model(config.model)
    inputs = input_checksums(config, ref)
    if manifest is not None:
        changed = preflight.changed_inputs(manifest, inputs, config)
        if changed:
            raise ConfigError(f"{where}: {'; '.join(changed)}: the run's stored results belong to the files as they "
                              "were; restore them, or start a new run with another --run-id")
    data = prepare_data(config, read_measured(config.resolve(config.measured), averages=config.averages), model)
    if where is not None and black_box(model):  # a black-box deck's solver folders: the run's own (reused)
        ref = dataclasses.replace(ref, workdir=str(Path(where).parent / FE_FOLDER))
        model = model.with_workdir(ref.workdir)
    lower, upper = search_box(model, config.lower, config.upper)
    modes = n_modes(model, data.frequencies_hz) if emulates_modes(config) else 0
    # what an FE run's worker needs, as the run had it: the closure's checks of a large model take the workers the
    # memory left holds (standalone at 500k DOFs two check workers of 6 GB beside the flow's 8 GB passed 21 GB)
    footprint = preflight.footprint_of(config, config.resolve(config.runs_dir) / MODEL_CACHE_FOLDER)
    return Problem(model, ref, data, lower, upper, modes, inputs, footprint and footprint.per_worker)
