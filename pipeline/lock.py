"""One writer per run directory: an advisory ``flock`` with the holder's pid and host.

The kernel drops a ``flock`` when its process dies, however it dies, so a lock left by a
killed run is stale by construction: the next run takes it over and rewrites the holder
record. (Advisory locks need a filesystem that honours ``flock``: local disks do; on NFS use
one run directory per driver.)
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from pathlib import Path
from types import TracebackType

from .errors import RunDirError, RunLockedError

__all__ = ["RunLock", "LOCK_NAME", "lock_holder"]

LOCK_NAME = ".arroyo.lock"


def lock_holder(rundir: Path) -> dict | None:
    """The live holder of the run directory's lock, or None when nobody holds it."""
    path = Path(rundir) / LOCK_NAME
    if not path.exists():
        return None
    # read-only: "a+" raised EROFS in `arroyo status` of an archived run directory on a
    # read-only mount; flock needs no write access
    with open(path) as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            try:
                return json.loads(fh.read() or "{}")
            except json.JSONDecodeError:
                return {}
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return None


class RunLock:
    """Context manager holding the exclusive lock of a run directory."""

    def __init__(self, rundir: Path) -> None:
        self.path = Path(rundir) / LOCK_NAME
        self._fh: object | None = None
        self.took_over: dict | None = None

    def __enter__(self) -> RunLock:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fh = open(self.path, "a+")
        except OSError as exc:  # a read-only run directory gave an EROFS traceback (exit 1)
            raise RunDirError(
                f"cannot lock the run directory {self.path.parent}: {exc.strerror or exc}; "
                "a run writes its directory: give --out a directory you can write (a "
                "read-only archive can still be read: status, query, report --output)"
            ) from None
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            try:
                holder = json.loads(fh.read() or "{}")
            except json.JSONDecodeError:
                holder = {}
            fh.close()
            raise RunLockedError(
                f"run directory {self.path.parent} is in use by arroyo pid "
                f"{holder.get('pid', '?')} on host {holder.get('host', '?')} since "
                f"{holder.get('since', '?')}; wait for that run to finish, or choose another "
                "--out"
            ) from None
        fh.seek(0)
        previous = fh.read()
        if previous.strip():
            try:
                self.took_over = json.loads(previous)
            except json.JSONDecodeError:
                self.took_over = {}
        fh.seek(0)
        fh.truncate()
        fh.write(
            json.dumps(
                {
                    "pid": os.getpid(),
                    "host": socket.gethostname(),
                    "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                }
            )
        )
        fh.flush()
        os.fsync(fh.fileno())
        self._fh = fh
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        fh = self._fh
        if fh is None:
            return
        fh.seek(0)  # type: ignore[attr-defined]
        fh.truncate()  # type: ignore[attr-defined]
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)  # type: ignore[attr-defined]
        fh.close()  # type: ignore[attr-defined]
        self._fh = None
