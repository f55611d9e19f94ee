"""One process per run folder: ``<run folder>/run.lock``.

The lock is an exclusive ``flock`` on ``run.lock``, which holds the owner's
pid, host and start time as JSON. The kernel releases a ``flock`` when its
process ends, however it ends (SIGKILL, power cut of the process), so a lock
left by a killed run is *stale*: the next run finds the file, gets the lock,
warns naming the dead owner, and takes over. A live owner keeps the lock and
the second process is refused with :class:`RunLockedError` naming the owner.
The pid and host are for the message; ``flock`` is what decides.

Within one process the lock is re-entrant (the CLI takes it, then the flow).
Locks on network filesystems depend on the filesystem's ``flock`` support.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import time
from pathlib import Path

__all__ = ["RunLock", "RunLockedError", "LOCK_NAME"]

LOCK_NAME = "run.lock"
log = logging.getLogger(__name__)
_held: dict[Path, list] = {}  # lock path -> [fd, depth]


class RunLockedError(RuntimeError):
    """Another live process holds the run folder's lock; the message names it."""


class RunLock:
    """Context manager holding the lock of one run folder (created if missing)."""

    def __init__(self, root: Path | str):
        self.root = Path(root)
        self.path = (self.root / LOCK_NAME).absolute()
        #: The owner record found when the lock was taken over from a dead process, else None.
        self.stale_owner: dict | None = None

    def acquire(self) -> "RunLock":
        if self.path in _held:
            _held[self.path][1] += 1
            return self
        self.root.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = _read_owner(fd)
                os.close(fd)
                raise RunLockedError(
                    f"{self.path}: run {self.root.name!r} is in use by pid {owner.get('pid', '?')} on host "
                    f"{owner.get('host', '?')} (since {owner.get('started', '?')}); wait for it to finish "
                    "or choose another --run-id"
                ) from None
            # Another process may have unlinked the file between our open and flock: lock the file in place.
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        owner = _read_owner(fd)
        if owner:
            self.stale_owner = owner
            log.warning("%s: stale lock of pid %s on host %s (started %s), which no longer runs; taking it over",
                        self.path, owner.get("pid", "?"), owner.get("host", "?"), owner.get("started", "?"))
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
        os.fsync(fd)
        _held[self.path] = [fd, 1]
        return self

    def release(self) -> None:
        entry = _held.get(self.path)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] == 0:
            del _held[self.path]
            # Unlink while still locked, so a waiting process either sees the new file or no file.
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
            os.close(entry[0])

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read_owner(fd: int) -> dict:
    try:
        data = os.pread(fd, 4096, 0)
        return json.loads(data) if data.strip() else {}
    except (OSError, ValueError):
        return {"pid": "?", "host": "? (unreadable lock file)"}
