"""Checks made before an updating run writes anything: inputs against the model, resume, disk.

Every check raises :class:`flows.config.ConfigError` or
:class:`tasks.io.measured.MeasuredDataError` with a message that names the
file and the key, sensor or frequency; the CLI turns them into exit code 2.

The model's frequency range
    A measured frequency must be above 0 Hz and at most the highest
    frequency the FE mesh resolves, :func:`max_frequency_hz`: the frequency
    at which the bending wavelength of the plates is six elements long (the
    usual minimum for linear elements; above it the FE model is too stiff
    and the updating would fit discretisation error). For the three-plate
    benchmark (10 mm steel, largest element 14.375 mm) this is 13.1 kHz; the
    measurement is at 106-295 Hz.

Memory
    A mesh model whose update would not fit in the memory this machine has available is refused before
    anything is assembled (:func:`check_memory`): the estimate of :mod:`flows.memory` (the model, one FE
    run's factorisation and Krylov space, the FE runs at once, the first assembly) against
    :func:`flows.memory.available_bytes`, with how much ``--n-jobs 1`` would need.

Disk
    The runs folder must be writable (checked by writing and removing a
    file: permission bits, read-only mounts and immutable folders all count,
    also for root) and the filesystem must have ``min_free_mb`` free, or,
    when that setting is 0, twice :func:`expected_output_mb`.
"""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from flows.config import ConfigError, UpdateConfig, stored_settings
from tasks.io.measured import MeasuredDataError

__all__ = ["max_frequency_hz", "check_inputs", "check_resume", "check_disk", "check_memory", "expected_output_mb",
           "ELEMENTS_PER_WAVELENGTH"]

#: The run folder's layout this version writes and resumes (flows.run.RECORD_VERSION). 3: every strategy under
#: one driver (tasks/driver.py): the batches' FE stages, the steps' stages with their ``inputs`` digest.
RECORD_VERSION = 3
#: Linear elements per bending wavelength below which the mesh no longer resolves the response.
ELEMENTS_PER_WAVELENGTH = 6


def max_frequency_hz(model_name: str) -> float:
    """Highest frequency the model's mesh resolves, Hz (see the module docstring).

    The six-elements rule needs the benchmark's plate thickness and element size;
    a model file has no such limit here (inf): its band is checked against its
    natural frequencies instead (:func:`check_band`).
    """
    if model_name.endswith(".toml"):
        return math.inf
    if model_name == "three_plate":
        from fe_core import benchmark as b

        h = max(max(x1 - x0 for x0, x1, _ in b.PLATES) / b.ELEMENTS_ALONG_X, b.ELEMENT_SIZE_Y)
        m = b.STEEL
        D = m.E * b.THICKNESS**3 / (12 * (1 - m.nu**2))  # plate bending stiffness, N m
        k = 2 * math.pi / (ELEMENTS_PER_WAVELENGTH * h)  # wavenumber of the shortest resolved wave, 1/m
        return k**2 * math.sqrt(D / (m.rho * b.THICKNESS)) / (2 * math.pi)
    raise ConfigError(f"config: key 'model': unknown model {model_name!r}")


def check_inputs(config: UpdateConfig, measured, model) -> None:
    """The measured data and the parameters fit the model.

    ``measured`` is the :class:`tasks.update_data.UpdateData` of the run (or a
    :class:`MeasuredFRF` in the legacy form): its channels were matched to the
    model already; the legacy form's sensor numbers are checked here, and every
    selected line against the highest frequency the model resolves (the
    refusal names the line in the file).
    """
    source = measured.source
    legacy = getattr(measured, "measured", measured).legacy
    want = np.arange(1, model.n_sensors + 1)
    have = np.asarray(measured.sensors)
    if legacy and (have.size != want.size or np.any(have != want)):
        missing = sorted(set(want.tolist()) - set(have.tolist()))
        extra = sorted(set(have.tolist()) - set(want.tolist()))
        raise MeasuredDataError(
            f"{source}: the model {config.model!r} has sensors 1..{model.n_sensors}; the file has "
            f"{have.size} sensors (missing {missing}, unknown {extra})"
        )
    f_max = max_frequency_hz(config.model)
    above = np.flatnonzero(np.asarray(measured.frequencies_hz) > f_max)
    if above.size:
        place = measured.line_place(int(above[0])) + ": " if hasattr(measured, "line_place") else ""
        raise MeasuredDataError(
            f"{source}: {place}frequency_hz {float(measured.frequencies_hz[above[0]])!r} is above {f_max:.0f} Hz, "
            f"the highest frequency the mesh of {config.model!r} resolves ({ELEMENTS_PER_WAVELENGTH} elements per bending "
            f"wavelength); {above.size} frequencies are out of range"
        )
    if config.model.endswith(".toml"):
        check_band(config, measured, model)
    if config.true_parameters is not None:
        truth = np.asarray(config.true_parameters, float)
        if truth.shape != (model.n_parameters,):
            raise ConfigError(f"config: key 'true_parameters': the model {config.model!r} has "
                              f"{model.n_parameters} parameters ({', '.join(model.parameter_names)}), "
                              f"got {truth.size}")


#: The measured band is "far outside" the model's modes beyond this factor (a mesh in mm with SI
#: materials puts every natural frequency 1000 times too low).
BAND_FACTOR = 30.0
#: Relative accuracy of a large model's eigenvalues in the band check (ARPACK's tol; the 150k panel: 21 solves
#: of the nominal K instead of 32 at machine precision, its six frequencies the same to 1e-8).
BAND_TOL = 1e-3


def check_band(config: UpdateConfig, measured, model) -> None:
    """Refuse a measured band far from the model's lowest natural frequencies (units mix-ups).

    With all alpha = 0: refused when every measured frequency is above
    ``BAND_FACTOR`` times the highest of the lowest six natural frequencies, or
    below the lowest one divided by ``BAND_FACTOR``.
    """
    from tasks.fe_runs import is_large, run_cores
    from fe_core.solvers import pardiso

    n = min(6, model.n_dofs - 1)
    try:  # a large model on the run's cores; its factor (the nominal K) is kept for the first FE run
        with pardiso.threads(run_cores(config) if is_large(model) else 1):
            # A large model's frequencies to BAND_TOL are plenty for a factor of BAND_FACTOR: 21 solves, not 32.
            loose = {"tol": BAND_TOL} if is_large(model) else {}
            freqs = model.natural_frequencies(np.zeros(model.n_segments), n_modes=n, **loose)
    except RuntimeError as exc:  # a black-box solver deck that its solver rejects (CcxError quotes its *ERROR lines)
        raise ConfigError(f"{config.model}: key 'deck': the nominal deck's modes: {exc}") from None
    lo, hi = float(np.min(measured.frequencies_hz)), float(np.max(measured.frequencies_hz))
    if lo > BAND_FACTOR * freqs[-1] or hi < freqs[0] / BAND_FACTOR:
        raise ConfigError(
            f"{config.model}: the model's natural frequencies ({', '.join(f'{f:.4g}' for f in freqs)} Hz at alpha = 0) "
            f"are far outside the measured band {lo:g}-{hi:g} Hz of {measured.source} (more than {BAND_FACTOR:g}x); "
            "check the units: a mesh in mm needs units = \"mm-t-s\" (E in MPa, rho in t/mm^3), "
            "a mesh in m needs SI materials"
        )


def footprint_of(config: UpdateConfig, cache_root: Path | None = None):
    """The :class:`flows.memory.Footprint` of the run's mesh model with its FE runs at once (one with a Dask
    cluster: its global rounds' runs are the cluster's), None for a model of another kind or a missing file (its
    reader names it). ``cache_root``: the model cache (a model found there needs no assembly)."""
    from fe_core.io import cache
    from fe_core.threads import cores
    from flows.memory import estimate
    from tasks.problem import model_checksum, model_path

    if not config.model.endswith(".toml"):
        return None
    path = model_path(config.model)
    if not path.exists():
        return None
    cached = False
    if cache_root is not None:
        try:
            cached = cache.lookup(cache_root, model_checksum(path)) is not None
        except (OSError, ValueError):
            cached = False
    jobs = cores(config.n_jobs) if config.fe_backend == "loky" else 1
    return estimate(path, jobs, cached=cached)


def check_memory(config: UpdateConfig, cache_root: Path | None = None):
    """Refuse a mesh model whose update needs more memory than the machine has available (exit 2), naming the
    model, the estimate and its parts, and what ``--n-jobs 1`` would need; returns the
    :class:`flows.memory.Footprint` (None for a model of another kind). ``cache_root``: the model cache (a
    model found there needs no assembly)."""
    from flows.memory import GB, available_bytes

    footprint = footprint_of(config, cache_root)
    if footprint is None:
        return None
    jobs = footprint.n_jobs
    avail = available_bytes()
    if footprint.total <= avail:
        return footprint
    single = footprint.with_jobs(1)
    if jobs > 1 and single.total <= avail:
        hint = (f"with --n-jobs 1 (one FE run at a time) it needs about {single.total / GB:.1f} GB: run with "
                "--n-jobs 1, or FE runs on a Dask cluster (--fe-backend dask)")
    else:
        hint = (f"even one FE run at a time needs about {single.total / GB:.1f} GB: use a coarser mesh or a "
                "machine with more memory")
    raise ConfigError(f"{config.model}: the update would not fit in memory: {footprint.describe()}; this machine "
                      f"has {avail / GB:.1f} GB available; {hint} (estimate from the mesh before any assembly; "
                      f"docs/results/scaling.md)")


def check_resume(config: UpdateConfig, root: Path, resumable: set[str], inputs: dict | None = None) -> None:
    """An existing run folder may be resumed only with the inputs and settings it was started with.

    ``inputs``: the checksums of what the run reads now (:func:`flows.problem.input_checksums`: the model file
    with its mesh/matrices, the measured file). Every difference is named in one message (exit 2), with how to
    start a new run instead; a run folder is never read back against other data.
    """
    manifests = [root / "manifest.json"] if (root / "manifest.json").exists() else sorted(
        root.glob("repeat=*/manifest.json"))
    for manifest in manifests[:1]:  # the repeats of one run share its inputs and settings
        try:
            record = json.loads(manifest.read_text())
            old = stored_settings(record["config"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{manifest}: unreadable run manifest ({exc}); choose a new --run-id") from None
        if record.get("record_version") != RECORD_VERSION:
            raise ConfigError(f"{manifest}: run {root.name!r} was made by an earlier version of this tool (another "
                              "layout of its run folder); finish it with that version or choose a new --run-id")
        problems = changed_inputs(record, inputs or {}, config)
        cfg = {**config.to_dict(), "repeats": old.get("repeats", config.repeats)}
        problems += [f"setting {k} ({old.get(k)!r} then, {cfg[k]!r} now)" for k in sorted(cfg)
                     if k not in resumable and old.get(k, cfg[k]) != cfg[k]]
        if problems:
            hint = ""
            if any(p.startswith("setting noise") for p in problems):
                hint = ("; to see the check or the intervals with another noise level, rerun those stages: "
                        f"python -m flows.update rerun --run-id {root.name} --stage check --noise <sigma>")
            raise ConfigError(f"{manifest}: run {root.name!r} was started with other inputs: "
                              f"{'; '.join(problems)}. Its stored results belong to those; resume with the same "
                              f"inputs, or start a new run with another --run-id (e.g. {root.name}-2){hint}")


#: The files a run reads, as named in its manifest's checksums, and the config key that names each.
INPUT_FILES = {"model_checksum": ("model", "the model file and the files it refers to"),
               "measured_checksum": ("measured", "the measured file")}


def changed_inputs(record: dict, inputs: dict, config: UpdateConfig) -> list[str]:
    """What of a run's input files changed since its manifest was written (same name, other content)."""
    out = []
    for key, (setting, what) in INPUT_FILES.items():
        stored, now = record.get(key), inputs.get(key)
        if stored is None or now is None or record.get("config", {}).get(setting) != getattr(config, setting):
            continue  # a name that changed is reported as a setting; a run made before the checksum existed
        if stored != now:
            out.append(f"{what} {getattr(config, setting)} (its content changed since the run was started: "
                       "SHA-256 differs)")
    return out


def expected_output_mb(config: UpdateConfig, n_values: int, m: int) -> float:
    """A generous estimate of a run's output size, MB.

    ``n_values`` responses (frequencies x sensors) per FE run, ``m`` parameters.
    Per FE run: its own file, its rows in ``fe.parquet`` and ``residuals.parquet``
    (about 100 bytes a value in all). Per iteration: ``w`` candidates of
    ``m + 2`` doubles, plus small tables. Repeats multiply.
    """
    from strategies import registry

    n_fe, iterations = registry.get(config.strategy).budget(config)
    per_run = n_fe * (n_values * 100 + 4096) + iterations * (config.w * (m + 2) * 8 + 64 * 1024)
    return config.repeats * per_run / 1e6


def check_disk(config: UpdateConfig, root: Path, required_mb: float) -> None:
    """The runs folder (or the run folder, when resuming) is writable and has ``required_mb`` free."""
    runs_dir = root.parent
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{runs_dir}: cannot create the runs folder ({exc.strerror}); "
                          "set runs_dir / --runs-dir to a writable folder") from None
    target = root if root.is_dir() else runs_dir
    try:
        fd, probe = tempfile.mkstemp(dir=target, prefix=".write-test-", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        why = "read-only filesystem" if exc.errno == errno.EROFS else exc.strerror
        raise ConfigError(f"{target}: cannot write into the {'run' if target == root else 'runs'} folder "
                          f"({why}); nothing was computed. Make it writable or set runs_dir / --runs-dir") from None
    free_mb = shutil.disk_usage(target).free / 1e6
    if free_mb < required_mb:
        raise ConfigError(f"{target}: {free_mb:.0f} MB free, the run needs at least {required_mb:.0f} MB "
                          "(key 'min_free_mb'); free space or choose another runs_dir")
