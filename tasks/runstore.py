"""The run folder: Parquet tables written once, atomically, per iteration and stage.

Layout (hive-style names)::

    data/runs/<run-id>/
        manifest.json                      config, seed, package versions, git commit
        iteration=1/stage=samples/samples.parquet
        iteration=1/stage=samples/_stage.json   written last: files and their SHA-256
        iteration=1/stage=fe/sample=000007.parquet   one per FE run, as it finishes
        iteration=1/stage=fe/fe.parquet
        ...
        summary.json

Every file is written to a temporary name in the same folder and renamed into
place, so a reader never sees half a file. A stage counts as finished only
when its ``_stage.json`` exists and every file it lists still has the
recorded checksum; anything else is recomputed.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import subprocess
import tempfile
import time
from importlib import metadata
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

__all__ = ["RunStore", "atomic_write_bytes", "atomic_write_json", "package_versions", "git_commit"]

log = logging.getLogger(__name__)

STAGE_RECORD = "_stage.json"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1, sort_keys=False, default=_json_default) + "\n").encode())


def _json_default(obj):
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _parquet_bytes(df: pd.DataFrame) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(df, preserve_index=False), sink)
    return sink.getvalue().to_pybytes()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def package_versions() -> dict[str, str]:
    out = {}
    for name in ("numpy", "scipy", "prefect", "joblib", "pandas", "pyarrow", "pyuff"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def git_commit(repo: Path | None = None) -> str | None:
    """The checked-out commit (with ``-dirty`` if the tree has changes), or None outside git."""
    repo = repo or Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True, check=True, timeout=10
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=repo, capture_output=True, text=True, check=True, timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("-dirty" if dirty else "")


class RunStore:
    """Read and write one run's folder.

    Parameters
    ----------
    root : path
        ``<runs_dir>/<run-id>``.
    """

    def __init__(self, root: Path | str):
        self.root = Path(root)

    # -- paths -----------------------------------------------------------
    def stage_dir(self, iteration: int, stage: str) -> Path:
        return self.root / f"iteration={iteration}" / f"stage={stage}"

    def path(self, iteration: int, stage: str, name: str) -> Path:
        return self.stage_dir(iteration, stage) / f"{name}.parquet"

    # -- tables ----------------------------------------------------------
    def write_table(self, iteration: int, stage: str, name: str, df: pd.DataFrame) -> Path:
        """Write one table of a stage atomically (the stage is not finished until :meth:`finish`)."""
        path = self.path(iteration, stage, name)
        atomic_write_bytes(path, _parquet_bytes(df))
        return path

    def read_table(self, iteration: int, stage: str, name: str | None = None) -> pd.DataFrame:
        return pd.read_parquet(self.path(iteration, stage, name or stage))

    def finish(self, iteration: int, stage: str, names: list[str], info: dict | None = None) -> None:
        """Mark a stage finished, recording its files' checksums."""
        files = {n: _sha256(self.path(iteration, stage, n)) for n in names}
        record = {"files": files, "finished_unix": time.time(), "info": info or {}}
        atomic_write_json(self.stage_dir(iteration, stage) / STAGE_RECORD, record)

    def is_finished(self, iteration: int, stage: str) -> bool:
        """True if the stage's record exists and all its files match their checksums."""
        record_path = self.stage_dir(iteration, stage) / STAGE_RECORD
        if not record_path.exists():
            return False
        try:
            record = json.loads(record_path.read_text())
        except (OSError, json.JSONDecodeError):
            log.warning("stage record %s is unreadable; the stage will be recomputed", record_path)
            return False
        for name, digest in record.get("files", {}).items():
            path = self.path(iteration, stage, name)
            if not path.exists() or _sha256(path) != digest:
                log.warning("%s is missing or does not match its checksum; the stage will be recomputed", path)
                return False
        return True

    def stage_info(self, iteration: int, stage: str) -> dict:
        return json.loads((self.stage_dir(iteration, stage) / STAGE_RECORD).read_text()).get("info", {})

    # -- per-sample FE results ------------------------------------------------
    def sample_path(self, iteration: int, sample_id: int) -> Path:
        return self.stage_dir(iteration, "fe") / f"sample={sample_id:06d}.parquet"

    def write_sample(self, iteration: int, sample_id: int, df: pd.DataFrame) -> None:
        atomic_write_bytes(self.sample_path(iteration, sample_id), _parquet_bytes(df))

    def finished_samples(self, iteration: int) -> dict[int, Path]:
        """Per-sample FE results already on disk (readable ones only)."""
        out = {}
        for path in sorted(self.stage_dir(iteration, "fe").glob("sample=*.parquet")):
            try:
                pq.read_metadata(path)
            except Exception:  # a file cut short by a crash of the filesystem, not by us
                log.warning("FE result %s is unreadable; that sample will be evaluated again", path)
                continue
            out[int(path.stem.split("=")[1])] = path
        return out

    # -- manifest ---------------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    def read_manifest(self) -> dict | None:
        if not self.manifest_path.exists():
            return None
        return json.loads(self.manifest_path.read_text())

    def write_manifest(self, manifest: dict) -> None:
        atomic_write_json(self.manifest_path, manifest)
