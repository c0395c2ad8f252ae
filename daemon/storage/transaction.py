"""The run database's transactions and its folder's claim (daemon/storage/recorder.py's
plumbing): one serialised transaction at a time, SQLite and OS errors as RecorderError."""

from __future__ import annotations

import fcntl
import logging
import os
import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO

logger = logging.getLogger(__name__)


class RecorderError(Exception):
    """The recording could not be written or read (disk full, unwritable, corrupt)."""


def claim(lock_path: Path) -> IO[str]:
    """Claim the data directory for this process: two recorders on one database would mark
    each other's live runs interrupted. The OS drops the claim when the process dies, even by
    SIGKILL, so a crash never leaves the directory locked."""
    handle = open(lock_path, "a+", encoding="utf-8")  # noqa: SIM115 -- held until close()
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        owner = handle.read().strip() or "unknown"
        handle.close()
        raise RecorderError(
            f"{lock_path.parent} is in use by another thermocomp process (pid {owner}): "
            "while it runs, start and follow runs through its API (POST /api/v1/runs), or "
            "use another folder (--data-dir, storage.data_dir)"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(str(os.getpid()))
    handle.flush()
    return handle


class Transaction:
    """One serialised transaction: BEGIN IMMEDIATE (a write) or BEGIN (a read snapshot) ...
    COMMIT, rolled back on error; SQLite and OS errors become RecorderError."""

    def __init__(
        self,
        db: sqlite3.Connection,
        lock: threading.Lock,
        path: Path,
        begin: str = "BEGIN IMMEDIATE",
        on_write: Callable[[str | None], None] | None = None,
    ) -> None:
        """``on_write``: told each write's outcome (its error, or None once committed)."""
        self._db, self._lock, self._path, self._begin = db, lock, path, begin
        self._on_write = on_write

    def __enter__(self) -> sqlite3.Connection:
        self._lock.acquire()
        try:
            self._db.execute(self._begin)
        except sqlite3.Error as err:
            self._lock.release()
            self._note(f"{self._path}: {err}")
            raise RecorderError(f"{self._path}: {err}") from err
        return self._db

    def _note(self, error: str | None) -> None:
        if self._on_write is not None:
            self._on_write(error)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, _: object
    ) -> None:
        try:
            self._finish(exc_type, exc)
        except RecorderError as err:
            self._note(str(err))
            raise
        if exc_type is None:
            self._note(None)
        elif isinstance(exc, (sqlite3.Error, OSError)):
            self._note(f"{self._path}: {exc}")

    def _finish(self, exc_type: type[BaseException] | None, exc: BaseException | None) -> None:
        try:
            if exc_type is None:
                self._db.execute("COMMIT")
            else:
                self._db.execute("ROLLBACK")
        except sqlite3.Error as err:
            if exc_type is None:
                try:
                    self._db.execute("ROLLBACK")
                except sqlite3.Error:
                    logger.debug("rollback after a failed commit failed too", exc_info=True)
                raise RecorderError(f"{self._path}: cannot commit: {err}") from err
        finally:
            self._lock.release()
        if isinstance(exc, sqlite3.Error):
            raise RecorderError(f"{self._path}: {exc}") from exc
