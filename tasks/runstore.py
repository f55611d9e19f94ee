"""The run folder: Parquet tables written once, atomically, per iteration and stage.

Layout (hive-style names)::

    runs/<run-id>/
        manifest.json                      config, seed, package versions, git commit
        iteration=1/stage=fe/runs.parquet
        iteration=1/stage=fe/_stage.json        written last: files and their SHA-256
        iteration=1/stage=fe/sample=000007.parquet   one per FE run, as it finishes
        iteration=1/stage=train/hyperparameters.parquet
        ...
        summary.json

Every file is written to a temporary name in the same folder and renamed into
place, so a reader never sees half a file. A stage counts as finished only
when its ``_stage.json`` exists and every file it lists still has the
recorded checksum and schema; anything else is recomputed, with a warning
naming the file. Every read-back (:meth:`RunStore.read_table`) checks the
file against the record again, so a file damaged after its stage finished is
never read as valid (:class:`CorruptFileError`).
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

from tasks.faults import kill_point

__all__ = ["RunStore", "CorruptFileError", "atomic_write_bytes", "atomic_write_file", "atomic_write_json",
           "package_versions", "git_commit"]

log = logging.getLogger(__name__)

STAGE_RECORD = "_stage.json"


class CorruptFileError(RuntimeError):
    """A run-folder file that does not match its stage record (or has none); the message names it."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    atomic_write_file(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_file(path: Path, write) -> None:
    """Write ``path`` through a temporary file ``.<name>.*.tmp`` beside it and a rename.

    ``write(tmp)`` writes the content to the temporary path (for writers that take a file
    name, e.g. meshio); the file is synced before the rename. A killed writer leaves only
    the temporary file, which :meth:`RunStore.remove_temporaries` removes.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        kill_point(f"before-rename:{path}")
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
    # Page checksums let a reader detect damaged data pages (the per-sample FE files have no record).
    pq.write_table(pa.Table.from_pandas(df, preserve_index=False), sink, write_page_checksum=True)
    return sink.getvalue().to_pybytes()


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _schema(path: Path) -> dict[str, str]:
    """Column name -> Arrow type of a Parquet file (raises on a file that is not Parquet)."""
    schema = pq.read_schema(path)
    return {name: str(schema.field(name).type) for name in schema.names}


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
        #: (iteration, sample_id, path, reason) of FE result files found invalid by this store.
        self.discarded: list[tuple[int, int, Path, str]] = []

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
        """A table of a finished stage, checked against the stage record first.

        Raises
        ------
        CorruptFileError
            If the stage has no record, the record does not list the table, or
            the file's checksum or schema differs from the record.
        """
        name = name or stage
        path = self.path(iteration, stage, name)
        record = self._record(iteration, stage)
        if record is None or name not in record.get("files", {}):
            raise CorruptFileError(f"{path}: not part of a finished stage (no entry in its {STAGE_RECORD})")
        problem = self._file_problem(path, record, name)
        if problem:
            raise CorruptFileError(f"{path}: {problem}; resume the run to recompute the stage")
        return pd.read_parquet(path)

    def finish(self, iteration: int, stage: str, names: list[str], info: dict | None = None) -> bool:
        """Mark a stage finished, recording its files' checksums and schemas.

        Returns True if the stage had a record before whose files differ from
        the new ones (a recomputed stage whose result changed: later stages
        that were built on it are stale, see :meth:`invalidate_after`).
        """
        kill_point(f"tables-written/iteration={iteration}/stage={stage}")
        files = {n: _sha256(self.path(iteration, stage, n)) for n in names}
        schemas = {n: _schema(self.path(iteration, stage, n)) for n in names}
        old = self._record(iteration, stage)
        changed = old is not None and old.get("files") != files
        record = {"files": files, "schemas": schemas, "finished_unix": time.time(), "info": info or {}}
        atomic_write_json(self.stage_dir(iteration, stage) / STAGE_RECORD, record)
        kill_point(f"stage-finished/iteration={iteration}/stage={stage}")
        return changed

    def _record(self, iteration: int, stage: str) -> dict | None:
        try:
            return json.loads((self.stage_dir(iteration, stage) / STAGE_RECORD).read_text())
        except (OSError, ValueError):
            return None

    @staticmethod
    def _file_problem(path: Path, record: dict, name: str) -> str | None:
        """Why ``path`` does not match its record entry, or None if it does."""
        if not path.exists():
            return "missing"
        if _sha256(path) != record["files"][name]:
            try:
                schema = _schema(path)
            except Exception as exc:  # pyarrow raises several types for a file that is not Parquet
                return f"truncated or not a Parquet file ({type(exc).__name__}: {exc})"
            expected = record.get("schemas", {}).get(name)
            if expected is not None and schema != expected:
                return f"wrong schema: columns {schema}, expected {expected}"
            return "content does not match the checksum in the stage record"
        return None

    def is_finished(self, iteration: int, stage: str) -> bool:
        """True if the stage's record exists and all its files match their checksums and schemas."""
        record_path = self.stage_dir(iteration, stage) / STAGE_RECORD
        if not record_path.exists():
            return False
        record = self._record(iteration, stage)
        if record is None or not isinstance(record.get("files"), dict):
            log.warning("stage record %s is unreadable; the stage will be recomputed", record_path)
            return False
        for name in record["files"]:
            path = self.path(iteration, stage, name)
            problem = self._file_problem(path, record, name)
            if problem:
                log.warning("%s: %s; iteration %d, stage %s will be recomputed", path, problem, iteration, stage)
                return False
        return True

    def invalidate_after(self, iteration: int, stage: str, order: tuple[str, ...]) -> list[Path]:
        """Remove the records of every stage after (iteration, stage) in ``order``, and the summary.

        Used when a recomputed stage changed: what was built on the old result
        must be recomputed too. Returns the records removed.
        """
        removed = []
        for record in sorted(self.root.glob(f"iteration=*/stage=*/{STAGE_RECORD}")):
            k = int(record.parent.parent.name.split("=", 1)[1])
            name = record.parent.name.split("=", 1)[1]
            base = name.split(".rerun-")[0]
            later = k > iteration or (k == iteration and base in order and stage in order
                                      and order.index(base) > order.index(stage))
            if later:
                record.unlink()
                removed.append(record)
        summary = self.root / "summary.json"
        if removed and summary.exists():
            summary.unlink()
        if removed:
            log.warning("iteration %d, stage %s changed on recomputation; %d later stages will be recomputed",
                        iteration, stage, len(removed))
        return removed

    def remove_temporaries(self) -> list[Path]:
        """Delete temporary files left by a killed writer (call only while holding the run's lock)."""
        stale = [p for p in self.root.rglob(".*.tmp") if p.is_file()]
        for p in stale:
            p.unlink()
        return stale

    def stage_files(self, iteration: int, stage: str) -> list[str]:
        """The tables a stage's record lists (none when it has no readable record)."""
        record = self._record(iteration, stage)
        return list((record or {}).get("files", {}))

    def stage_info(self, iteration: int, stage: str) -> dict:
        return json.loads((self.stage_dir(iteration, stage) / STAGE_RECORD).read_text()).get("info", {})

    # -- per-sample FE results ------------------------------------------------
    def sample_path(self, iteration: int, sample_id: int) -> Path:
        return self.stage_dir(iteration, "fe") / f"sample={sample_id:06d}.parquet"

    def write_sample(self, iteration: int, sample_id: int, df: pd.DataFrame) -> None:
        atomic_write_bytes(self.sample_path(iteration, sample_id), _parquet_bytes(df))

    def finished_samples(self, iteration: int, check=None) -> dict[int, Path]:
        """Per-sample FE results already on disk (valid ones only).

        Each file is read in full with its page checksums verified; ``check``,
        if given, is called as ``check(sample_id, table)`` and returns the
        reason a readable table is not a valid result (or None). An invalid
        file is renamed to ``<name>.corrupt-<unix time>`` (kept for
        inspection), logged with a warning naming it, and left out, so that
        sample is evaluated again.
        """
        out = {}
        for path in sorted(self.stage_dir(iteration, "fe").glob("sample=*.parquet")):
            sid = int(path.stem.split("=")[1])
            try:
                table = pq.read_table(path, page_checksum_verification=True).to_pandas()
                problem = check(sid, table) if check is not None else None
            except Exception as exc:  # pyarrow raises several types for damaged files
                problem = f"unreadable ({type(exc).__name__}: {exc})"
            if problem:
                self.discarded.append((iteration, sid, path, problem))
                log.warning("FE result %s is not valid (%s); that sample will be evaluated again", path, problem)
                path.rename(path.with_name(f"{path.name}.corrupt-{time.time():.0f}"))
                continue
            out[sid] = path
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
