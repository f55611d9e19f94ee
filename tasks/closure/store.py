"""The closure's folder, :class:`ClosureStore`: one sub-folder per step with Parquet tables written atomically
and a record of their SHA-256 (see :mod:`tasks.closure`); and the conversions between its tables and the
fits and candidates of :mod:`fe_core.closure` (:func:`residual_table`, the baseline fit, the screened
candidates)."""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from fe_core.closure import fits, screening
from fe_core.closure.effects import Applied, extended_frf
from fe_core.inference.residual import log_residual
from tasks.runstore import atomic_write_bytes, atomic_write_json

__all__ = ["ClosureStore", "residual_table"]


log = logging.getLogger(__name__)
STEP_RECORD = "_step.json"


def _logger():
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:
        return log


# -- the folder -----------------------------------------------------------------------------------------
def _parquet_bytes(df: pd.DataFrame) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(df, preserve_index=False), sink)
    return sink.getvalue().to_pybytes()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class ClosureStore:
    """One closure's folder: steps of Parquet tables with checksummed records."""

    def __init__(self, root: Path | str):
        self.root = Path(root)

    def step_dir(self, step: str) -> Path:
        return self.root / f"step={step}"

    def path(self, step: str, name: str) -> Path:
        return self.step_dir(step) / f"{name}.parquet"

    def write_table(self, step: str, name: str, df: pd.DataFrame) -> Path:
        path = self.path(step, name)
        atomic_write_bytes(path, _parquet_bytes(df))
        return path

    def read_table(self, step: str, name: str | None = None) -> pd.DataFrame:
        return pd.read_parquet(self.path(step, name or step))

    def finish(self, step: str, names: list[str], info: dict | None = None) -> None:
        files = {n: _sha256(self.path(step, n)) for n in names}
        atomic_write_json(self.step_dir(step) / STEP_RECORD,
                          {"files": files, "finished_unix": time.time(), "info": info or {}})

    def is_finished(self, step: str) -> bool:
        record = self.step_dir(step) / STEP_RECORD
        if not record.exists():
            return False
        try:
            files = json.loads(record.read_text()).get("files", {})
        except (OSError, json.JSONDecodeError):
            return False
        return all(self.path(step, n).exists() and _sha256(self.path(step, n)) == d for n, d in files.items())

    def info(self, step: str) -> dict:
        return json.loads((self.step_dir(step) / STEP_RECORD).read_text()).get("info", {})

    def write_settings(self, settings: dict) -> None:
        path = self.root / "settings.json"
        if path.exists():
            old = json.loads(path.read_text())
            changed = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k)
                             and k not in ("n_jobs", "max_minutes"))
            if changed:
                raise ValueError(f"{path}: this closure was started with other settings ({', '.join(changed)}); "
                                 f"use the same settings to resume, or another --name")
        atomic_write_json(path, settings)


def _done(store: ClosureStore, step: str) -> bool:
    if store.is_finished(step):
        _logger().info("closure step %s: finished earlier, read back", step)
        return True
    return False


# -- conversions ------------------------------------------------------------------------------------------
def residual_table(freqs: np.ndarray, sensors: np.ndarray, relative: np.ndarray, logres: np.ndarray) -> pd.DataFrame:
    """Long table (frequency_hz, sensor, residual, log_residual), frequency-major; residual is Eq. 5's."""
    p, n = relative.shape
    return pd.DataFrame({"frequency_hz": np.repeat(np.asarray(freqs, float), n),
                         "sensor": np.tile(np.asarray(sensors, np.int64), p),
                         "residual": relative.ravel(), "log_residual": logres.ravel()})


def _fit_from_parameters(model, library, freqs, u, alpha, effect, location, values, evaluations=0,
                         seconds=0.0, message="", amplitude=None) -> fits.Fit:
    """Rebuild a fit from stored parameters: its model amplitudes as stored with them (``amplitude``, flat, as many
    as ``u`` holds), else from one FRF evaluation (a store written before they were kept). At 500k DOFs an FRF
    evaluation takes 1.5-2 minutes; a far-off case's decision rebuilt its 38 checks' fits one FE solve each."""
    applied = [] if effect is None else [Applied(library[effect], location, np.asarray(values, float))]
    stored = None if amplitude is None else np.asarray(amplitude, dtype=float)
    if stored is not None and stored.size == np.size(u) and np.all(np.isfinite(stored)):
        amp = stored.reshape(np.shape(u))
    else:
        amp = np.abs(extended_frf(model, alpha, freqs, applied))
    return fits.Fit(alpha=np.asarray(alpha, float), effect=effect, location=location,
                    values=np.asarray(values, float), model_amplitude=amp, residual=log_residual(amp, u),
                    evaluations=int(evaluations), seconds=float(seconds), message=message,
                    added=applied[0] if applied else None)


def _param_table(fit: fits.Fit, library: dict) -> pd.DataFrame:
    names = [f"alpha_{i + 1}" for i in range(fit.alpha.size)]
    values = list(map(float, fit.alpha))
    if fit.effect is not None:
        names += list(library[fit.effect].parameters)
        values += list(map(float, fit.values))
    return pd.DataFrame({"name": names, "value": values})


def _baseline_fit(store, model, freqs, u) -> fits.Fit:
    df = store.read_table("baseline")
    info = store.info("baseline")
    alpha = df.loc[df["name"].str.startswith("alpha_"), "value"].to_numpy()
    stored = store.path("baseline", "amplitude").exists()  # not in a store written before they were kept
    amplitude = store.read_table("baseline", "amplitude")["amplitude"].to_numpy() if stored else None
    return _fit_from_parameters(model, {}, freqs, u, alpha, None, None, np.zeros(0), info["evaluations"],
                                info["seconds"], info["message"], amplitude=amplitude)


def _screened(store) -> list[screening.Candidate]:
    df = store.read_table("screen")
    return [screening.Candidate(effect=r.effect, location=r.location, n_locations=int(r.n_locations),
                                linear_values=np.array(json.loads(r.linear_values)), linear_rss=float(r.linear_rss),
                                linear_explained=float(r.linear_explained), linear_delta_bic=float(r.linear_delta_bic),
                                linear_delta_ebic=float(r.linear_delta_ebic))
            for r in df.itertuples(index=False)]
