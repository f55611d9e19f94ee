"""The log of a run's FE runs, ``fe_evaluations.jsonl`` (split from :mod:`tasks.fe_runs`, which re-exports it)."""

from __future__ import annotations

import json
import os
from pathlib import Path

__all__ = ["FE_LOG", "append_log", "read_fe_log"]

FE_LOG = "fe_evaluations.jsonl"


def append_log(store, entry: dict) -> None:
    """Append one line to ``fe_evaluations.jsonl`` with a single write (a kill cannot split it)."""
    path = store.root / FE_LOG
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        lead = b""
        if os.fstat(fd).st_size:  # a line cut short by a crash of the filesystem: start a new line
            with open(path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                lead = b"" if fh.read(1) == b"\n" else b"\n"
        os.write(fd, lead + (json.dumps(entry) + "\n").encode())
    finally:
        os.close(fd)


def read_fe_log(root: Path | str) -> list[dict]:
    """The entries of a run's ``fe_evaluations.jsonl`` (unparsable lines are skipped).

    Each entry has ``iteration``, ``stage``, ``sample_id`` and ``event``: ``evaluated`` (an FE run whose
    result was written), ``recovered`` (a result found on disk without its log line, written back on resume:
    still one FE run) or ``discarded`` (a result file set aside; that point is evaluated again).
    """
    path = Path(root) / FE_LOG
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue
            entry.setdefault("event", "evaluated")
            out.append(entry)
    return out
