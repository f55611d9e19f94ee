"""One updating run, whatever its strategy: problem -> manifest -> strategy -> summary.

:func:`run_update` resolves the run's problem once (:func:`flows.problem.resolve`), takes the run's lock,
writes ``manifest.json`` and ``measured.parquet``, runs the strategy of the registry
(:mod:`strategies.registry`) under the one driver (:func:`flows.drive.run_strategy`), then the intervals,
``model.vtu`` and ``summary.json`` (:mod:`flows.summary`). Repeats run the same problem with seeds
``seed .. seed + repeats - 1`` in ``repeat=<i>/`` folders.
"""

from __future__ import annotations

import datetime as dt
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from flows import preflight
from flows import problem as problems
from flows.config import ConfigError, UpdateConfig, stored_settings
from flows.drive import run_strategy
from flows.summary import finish_run, repeat_summary, run_summary
from strategies import registry
from tasks.runlock import RunLock
from tasks.runstore import RunStore, _parquet_bytes, atomic_write_bytes, atomic_write_json, git_commit, package_versions
from tasks.update_data import UpdateData

__all__ = ["run_update", "single_run", "write_manifest", "write_measured_table", "RECORD_VERSION"]

#: The layout of the run folder this version writes (:data:`flows.preflight.RECORD_VERSION`); a run folder of
#: another layout is not resumed (:func:`flows.preflight.check_resume`).
RECORD_VERSION = preflight.RECORD_VERSION


def run_update(config: UpdateConfig, problem=None) -> dict:
    """The whole run (all repeats); returns the summary written to ``summary.json``. ``problem``: resolved
    already by the caller (:func:`flows.problem.resolve`), or here."""
    t0 = time.perf_counter()
    problem = problem or problems.resolve(config)
    root = config.resolve(config.runs_dir) / config.run_id
    with RunLock(root):
        stale = RunStore(root).remove_temporaries()
        if stale:
            print(f"removed {len(stale)} temporary files left by an interrupted run")
        if config.repeats == 1:
            return single_run(problem, config, RunStore(root), t0)
        runs = []
        for i in range(config.repeats):
            sub = config.replace(seed=config.seed + i, repeats=1)
            runs.append(single_run(problem, sub, RunStore(root / f"repeat={i}"), time.perf_counter()))
        summary = repeat_summary(config, runs, time.perf_counter() - t0, root)
        atomic_write_json(root / "summary.json", summary)
        return summary


def single_run(problem, config: UpdateConfig, store: RunStore, t0: float) -> dict:
    """One run of the strategy, then its summary (intervals, model.vtu, summary.json)."""
    write_manifest(store, config, problem)
    for line in problem.data.describe():
        print(f"measured: {line}")
    write_measured_table(store, problem.data)
    iteration, outcome = run_strategy(problem, config, store)
    summary = run_summary(problem, config, store, iteration, outcome, time.perf_counter() - t0)
    return finish_run(problem, config, store, iteration, summary, outcome["intervals"])


def write_measured_table(store: RunStore, data: UpdateData) -> None:
    """``<run>/measured.parquet``: every measured line and channel as read (receptance, sign-corrected), with
    ``used`` (the value enters the residual), ``selected`` (its line is selected) and the channel's match."""
    m = data.measured
    p, n = m.amplitude.shape
    lines = data.selection_lines
    used = np.zeros((p, n), dtype=bool)
    used[lines] = data.mask
    signs = np.array([c["sign"] for c in data.channel_info], float)
    table = pd.DataFrame({
        "frequency_hz": np.repeat(m.frequencies_hz, n), "sensor": np.tile(m.sensors, p).astype(np.int64),
        "channel": np.tile([c["label"] for c in data.channel_info], p),
        "model_sensor": np.tile([c["sensor"] or "" for c in data.channel_info], p),
        "model_excitation": np.tile([c["excitation"] for c in data.channel_info], p),
        "amplitude": m.amplitude.ravel(), "selected": np.repeat(lines, n), "used": used.ravel(),
    })
    if m.complex_frf is not None:
        z = (m.complex_frf * signs).ravel()
        table["real"], table["imag"] = z.real, z.imag
    if m.coherence is not None:
        table["coherence"] = m.coherence.ravel()
    atomic_write_bytes(store.root / "measured.parquet", _parquet_bytes(table))


def write_manifest(store: RunStore, config: UpdateConfig, problem=None) -> None:
    """``manifest.json``: written when the run starts; a resume adds its time (settings must agree)."""
    old = store.read_manifest()
    cfg = config.to_dict()
    if old is not None:
        before = stored_settings(old["config"])
        changed = {k for k in cfg if before.get(k, cfg[k]) != cfg[k]} - problems.RESUMABLE_CHANGES  # as preflight
        if changed:
            raise ConfigError(
                f"{store.manifest_path}: run {store.root.name!r} was started with other settings "
                f"({', '.join(sorted(changed))}); resume with the same settings or choose a new --run-id"
            )
        old.setdefault("resumes", []).append(_now())
        store.write_manifest(old)
        return
    store.write_manifest({
        "run_id": store.root.name,
        "created": _now(),
        "record_version": RECORD_VERSION,
        "config": cfg,
        "seed": config.seed,
        "versions": {"python": sys.version.split()[0], **package_versions()},
        "git_commit": git_commit(),
        "stages": list(registry.get(config.strategy).stages),
        **({**problem.inputs, "measured_data": problem.data.manifest_entry()} if problem is not None else {}),
    })


def _now() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")


def run_root(config: UpdateConfig) -> Path:
    return config.resolve(config.runs_dir) / config.run_id
