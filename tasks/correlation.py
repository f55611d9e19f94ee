"""Correlation analysis (Section 3.5): Monte Carlo FE samples, Pearson coefficients, sensitivity.

Plain functions over a folder (the Prefect flow is :mod:`flows.correlation`)::

    <folder>/
        meta.json                       model, frequencies, seed, chunk size, box (fixed at creation)
        fe/chunk=000000.parquet         FE results of samples 0 .. chunk-1, written atomically
        fe/chunk=000001.parquet         ...
        correlation.parquet             parameter, sensor, frequency_hz, rho, n_samples
        sensitivity.parquet             reference, parameter, sensor, frequency_hz, dlog_amplitude
        identifiability.json            singular values, directions, verdicts per reference point

Samples are drawn per chunk from ``default_rng([seed, chunk])``, so sample
``i`` does not depend on how many samples are asked for: a second call with
a larger N reuses every finished chunk, and a killed run loses only the
chunks in flight.
"""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from fe_core.solvers.sensitivity import identifiability, log_amplitude_jacobian, pearson_correlation
from strategies import table2
from tasks.runstore import _parquet_bytes, atomic_write_bytes, atomic_write_json
from tasks.fe_runs import evaluate_sample

__all__ = [
    "CorrelationError",
    "prepare_folder",
    "chunk_samples",
    "evaluate_chunk",
    "finished_chunks",
    "load_amplitudes",
    "correlation_table",
    "sensitivity_tables",
]

log = logging.getLogger(__name__)

_CHUNK = re.compile(r"^chunk=(\d+)\.parquet$")


class CorrelationError(ValueError):
    """A correlation folder that does not fit the request; the message names the file and key."""


def prepare_folder(folder: Path, meta: dict) -> dict:
    """Create ``meta.json`` or check that an existing one matches ``meta`` (same model, frequencies, seed...)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "meta.json"
    if path.exists():
        old = json.loads(path.read_text())
        for key, value in meta.items():
            same = (np.allclose(old.get(key, []), value, rtol=0, atol=1e-9) if key == "frequencies_hz"
                    else old.get(key) == value)
            if not same:
                raise CorrelationError(
                    f"{path}: key '{key}' is {old.get(key)!r} here but {value!r} was asked for; "
                    f"use the same settings to resume, or another --run-id")
        return old
    atomic_write_json(path, meta)
    return meta


def chunk_samples(seed: int, chunk: int, size: int, m: int, lower: float, upper: float) -> np.ndarray:
    """The parameter samples of one chunk, uniform in the box, shape (size, m)."""
    rng = np.random.default_rng([seed, chunk])
    return table2.uniform_samples(size, np.full(m, lower), np.full(m, upper), rng)


def chunk_path(folder: Path, chunk: int) -> Path:
    return folder / "fe" / f"chunk={chunk:06d}.parquet"


def evaluate_chunk(folder: str, chunk: int, meta: dict, ref, names: list[str]) -> int:
    """FE runs of one chunk's samples, written to ``fe/chunk=<c>.parquet``; returns the chunk index.

    Runs in a worker process (``ref``: the model's :class:`tasks.problem.ModelRef`, ``names``: its
    parameters). Failed FE runs are kept with ``status = "failed"`` (see
    :func:`tasks.fe_runs.evaluate_sample`) and left out of the statistics.
    """
    m, size = int(meta["n_parameters"]), int(meta["chunk_size"])
    X = chunk_samples(meta["seed"], chunk, size, m, meta["lower"], meta["upper"])
    freqs = np.asarray(meta["frequencies_hz"], dtype=float)
    parts = []
    for j, alpha in enumerate(X):
        df = evaluate_sample(ref, chunk * size + j, alpha, freqs)
        for i, name in enumerate(names):
            df[name] = alpha[i]
        parts.append(df.drop(columns=["message", "pid"]))
    atomic_write_bytes(chunk_path(Path(folder), chunk), _parquet_bytes(pd.concat(parts, ignore_index=True)))
    return chunk


def finished_chunks(folder: Path) -> set[int]:
    """Chunks with a readable result file."""
    out = set()
    for p in (folder / "fe").glob("chunk=*.parquet"):
        m = _CHUNK.match(p.name)
        if not m:
            continue
        try:
            pq.read_metadata(p)
        except Exception:
            log.warning("%s is unreadable; that chunk will be evaluated again", p)
            continue
        out.add(int(m.group(1)))
    return out


def chunks_needed(n_samples: int, chunk_size: int) -> list[int]:
    return list(range(math.ceil(n_samples / chunk_size)))


def load_amplitudes(folder: Path, n_samples: int, meta: dict, names: list[str]) -> tuple[np.ndarray, np.ndarray,
                                                                                      pd.MultiIndex, int]:
    """The first ``n_samples`` samples and their FRF amplitudes.

    Returns
    -------
    X : ndarray, shape (r, m)
        Parameters of the successful runs.
    A : ndarray, shape (r, p * n)
        Amplitudes, m/N, columns frequency-major with sensors fastest.
    columns : MultiIndex
        ``(frequency_hz, sensor)`` of each column of ``A``.
    failed : int
        Runs left out because the FE model failed.
    """
    size = int(meta["chunk_size"])
    frames = []
    for c in chunks_needed(n_samples, size):
        path = chunk_path(folder, c)
        if not path.exists():
            raise CorrelationError(f"{path}: missing; run the FE samples first")
        frames.append(pd.read_parquet(path))
    fe = pd.concat(frames, ignore_index=True)
    fe = fe[fe["sample_id"] < n_samples]
    status = fe.groupby("sample_id")["status"].first()
    ok_ids = status.index[status == "ok"]
    fe = fe[fe["sample_id"].isin(ok_ids)]
    fe = fe.assign(amplitude=np.hypot(fe["real"], fe["imag"]))
    wide = fe.pivot_table(index="sample_id", columns=["frequency_hz", "sensor"], values="amplitude").sort_index(axis=1)
    cols = names
    X = fe.groupby("sample_id")[cols].first().loc[wide.index].to_numpy()
    return X, wide.to_numpy(), wide.columns, int((status != "ok").sum())


def parameter_names(meta: dict, model) -> list[str]:
    """The model's parameter names (``alpha_i``, and ``gamma_j`` for updated masses); ``meta["n_parameters"]``
    of them."""
    names = model.parameter_names
    if len(names) != int(meta["n_parameters"]):
        raise CorrelationError(f"the model {meta['model']} has {len(names)} parameters ({', '.join(names)}), "
                               f"the samples {meta['n_parameters']}")
    return names


def correlation_table(X: np.ndarray, A: np.ndarray, columns: pd.MultiIndex,
                      names: list[str] | None = None) -> pd.DataFrame:
    """Eq. (16) for every parameter and response: ``parameter, sensor, frequency_hz, rho, rho_log, n_samples``.

    ``rho`` is the paper's coefficient with the amplitude; ``rho_log`` is the
    same with ``log |Z|``, which the few samples whose resonance falls on a
    measured frequency (amplitudes up to 100x the median) do not dominate.
    """
    rho = pearson_correlation(X, A)  # (m, p * n)
    rho_log = pearson_correlation(X, np.log(A))
    m = X.shape[1]
    freqs = columns.get_level_values(0).to_numpy(float)
    sensors = columns.get_level_values(1).to_numpy(int)
    return pd.DataFrame({
        "parameter": np.repeat(names or [f"alpha_{i + 1}" for i in range(m)], len(columns)),
        "sensor": np.tile(sensors, m),
        "frequency_hz": np.tile(freqs, m),
        "rho": rho.ravel(),
        "rho_log": rho_log.ravel(),
        "n_samples": X.shape[0],
    })


def sensitivity_tables(model, references: dict[str, np.ndarray], freqs_hz, noise: float,
                       tolerance: float) -> tuple[pd.DataFrame, dict, dict]:
    """Normalised sensitivity ``d log|Z| / d alpha`` and its identifiability summary at each reference point.

    Returns
    -------
    table : DataFrame
        ``reference, parameter, sensor, frequency_hz, dlog_amplitude``.
    summary : dict
        JSON-ready, one entry per reference point.
    results : dict of str to :class:`fe_core.solvers.sensitivity.Identifiability`
    """
    freqs = np.asarray(freqs_hz, dtype=float)
    n, m = model.n_sensors, model.n_parameters
    names = model.parameter_names
    rows, summary, results = [], {}, {}
    for label, alpha in references.items():
        J = log_amplitude_jacobian(model, alpha, freqs)  # (p * n, m)
        for i, name in enumerate(names):
            rows.append(pd.DataFrame({"reference": label, "parameter": name,
                                      "sensor": np.tile(np.arange(1, n + 1), freqs.size),
                                      "frequency_hz": np.repeat(freqs, n), "dlog_amplitude": J[:, i]}))
        r = identifiability(J, names, noise=noise, tolerance=tolerance)
        results[label] = r
        summary[label] = {
            "alpha": [float(v) for v in alpha],
            "singular_values": r.singular_values.tolist(),
            "condition_number": r.condition_number,
            "directions": {f"{j + 1}": {"singular_value": float(r.singular_values[j]),
                                        "combination": r.describe_direction(j),
                                        "vector": r.directions[j].tolist(),
                                        "std_at_noise": float(r.direction_std[j])}
                           for j in range(m)},
            "parameters": {name: {"std_at_noise": float(r.std[i]), "sensitivity_norm": float(r.column_norms[i]),
                                  "identifiable": bool(r.identifiable[i])} for i, name in enumerate(names)},
            "noise": noise,
            "tolerance": tolerance,
            "verdict": r.summary_lines(),
        }
    return pd.concat(rows, ignore_index=True), summary, results
