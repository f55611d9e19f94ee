"""Assembled models cached on disk and memory-mapped, so a large model is read and assembled once.

Reading a large mesh model is slow and memory-hungry (a 464k-DOF tet10 bracket: 95 s and 5 GB of peak
memory, most of it the assembly's temporaries). A run reads its model once in the main process and writes it
here; its FE workers (and the next run of the same model) map the cached arrays instead of assembling again:
the pages of the segment matrices are then shared between the processes through the page cache, not copied
into each.

The model is pickled (protocol 5) with every array out of band: ``model.pkl`` holds the small structure,
``arrays.bin`` the arrays' bytes (each 64-byte aligned), ``index.json`` where each lies and what the entry was
made from. :func:`load` maps ``arrays.bin`` copy-on-write (``mmap.ACCESS_COPY``): arrays read from the shared
pages; a process that writes into one gets its own copy of the pages it writes (nothing is written back).

An entry's folder is named by :func:`cache_key`: the model's checksum (SHA-256 over the model file and the
files it refers to, :func:`tasks.problem.model_checksum`), the source of ``fe_core`` (the code that assembled
it) and :data:`FORMAT`. A changed model file, mesh or matrix file, or another version of the code, gives
another key: a stale entry is never served, it is only left to be evicted (:func:`prune`, the oldest beyond
:data:`KEEP` entries). Entries are written into a temporary folder and renamed into place, so a reader never
sees half an entry.
"""

from __future__ import annotations

import hashlib
import json
import logging
import mmap
import os
import pickle
import shutil
import tempfile
import time
from pathlib import Path

__all__ = ["FORMAT", "KEEP", "cache_key", "code_digest", "save", "load", "lookup", "prune", "entry_info"]

log = logging.getLogger(__name__)

#: Layout of an entry; part of the key.
FORMAT = 1
#: Entries kept in a cache folder (the most recently used).
KEEP = 3
#: Alignment of each array in ``arrays.bin``, bytes.
ALIGN = 64

_DIGEST: str | None = None


def code_digest() -> str:
    """SHA-256 of every ``.py`` file of ``fe_core`` (path and content): an entry is valid only for the code that
    wrote it."""
    global _DIGEST
    if _DIGEST is None:
        root = Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        _DIGEST = h.hexdigest()
    return _DIGEST


def cache_key(checksum: str) -> str:
    """The entry name of a model with this checksum (see the module docstring)."""
    if not checksum:
        raise ValueError("a model is cached by its checksum; got none")
    return hashlib.sha256(f"{checksum}:{code_digest()}:{FORMAT}".encode()).hexdigest()[:32]


def lookup(root: Path | str, checksum: str) -> Path | None:
    """The entry folder of ``checksum`` under ``root`` when it exists and is complete, else None."""
    folder = Path(root) / cache_key(checksum)
    return folder if (folder / "index.json").is_file() else None


def save(model, root: Path | str, checksum: str, info: dict | None = None) -> Path:
    """Write ``model`` as the entry of ``checksum`` under ``root`` and return its folder (an existing complete
    entry is kept as it is). ``info``: small JSON-able facts stored beside it (sizes, the factor's fill)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    final = root / cache_key(checksum)
    if (final / "index.json").is_file():
        return final
    buffers: list[pickle.PickleBuffer] = []
    payload = pickle.dumps(model, protocol=5, buffer_callback=buffers.append)
    tmp = Path(tempfile.mkdtemp(prefix=".writing-", dir=root))
    try:
        spans, offset = [], 0
        with open(tmp / "arrays.bin", "wb") as fh:
            for buf in buffers:
                raw = buf.raw()
                pad = -offset % ALIGN
                fh.write(b"\0" * pad)
                offset += pad
                fh.write(raw)
                spans.append((offset, raw.nbytes))
                offset += raw.nbytes
        (tmp / "model.pkl").write_bytes(payload)
        index = {"format": FORMAT, "checksum": checksum, "code": code_digest(), "spans": spans,
                 "bytes": offset, "written": time.time(), "info": info or {}}
        (tmp / "index.json").write_text(json.dumps(index))
        try:
            os.rename(tmp, final)
        except OSError:  # another process wrote the same entry meanwhile: theirs is as good
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info("model cached: %s (%.0f MB)", final, offset / 1e6)
    return final


def entry_info(folder: Path | str) -> dict:
    """The ``info`` stored with an entry (empty for none)."""
    return json.loads((Path(folder) / "index.json").read_text()).get("info", {})


def load(folder: Path | str):
    """The model of an entry, its arrays mapped copy-on-write from ``arrays.bin``.

    Raises
    ------
    ValueError
        An entry of another format or code, or whose array file is shorter than its index says.
    """
    folder = Path(folder)
    index = json.loads((folder / "index.json").read_text())
    if index.get("format") != FORMAT or index.get("code") != code_digest():
        raise ValueError(f"{folder}: a model cache entry of another format or code version")
    path = folder / "arrays.bin"
    size = path.stat().st_size
    if size < index["bytes"]:
        raise ValueError(f"{path}: {size} bytes, the index says {index['bytes']}")
    buffers = []
    if size:
        with open(path, "rb") as fh:
            mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_COPY)
        view = memoryview(mapped)
        buffers = [view[o:o + n] for o, n in index["spans"]]
    model = pickle.loads((folder / "model.pkl").read_bytes(), buffers=buffers)
    os.utime(folder / "index.json")  # used now: the last to be evicted
    return model


def prune(root: Path | str, keep: int = KEEP) -> list[Path]:
    """Remove all but the ``keep`` most recently used entries under ``root`` (and stale temporary folders);
    returns what was removed."""
    root = Path(root)
    if not root.is_dir():
        return []
    entries, removed = [], []
    for folder in root.iterdir():
        index = folder / "index.json"
        if index.is_file():
            entries.append((index.stat().st_mtime, folder))
        elif folder.name.startswith(".writing-") and time.time() - folder.stat().st_mtime > 24 * 3600:
            entries.append((0.0, folder))
    entries.sort(reverse=True)
    for _, folder in entries[keep:]:
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed
