"""Crash-safe recording of runs and steps in SQLite (WAL, synchronous=FULL).

Every step is committed in its own transaction, in step order: before the next step begins
(arm and followed runs) or while the next steps move (two-link runs, whose measurement
overlaps the next moves: daemon/run/step.py MeasuringStep, daemon/run/session.py
MEASURING_STEPS). A crash (even SIGKILL) loses at most the steps in progress (normally one; at
most three measuring and one moving) and never leaves a partial one: SQLite's WAL
commit is atomic, and ``synchronous=FULL`` makes it durable. A run found in a live state when
the recorder opens was left by a crash and is marked ``interrupted``; its steps are kept.

The step columns (StepRecord's fields, in order) are the contract with daemon.analysis and
every export; a database of an older schema gains the missing columns when it is opened.
All methods are synchronous: the daemon calls the writing ones from one worker thread so that
the event loop never waits on an fsync. Writes are serialised by a lock on one connection;
each reading thread has its own query-only connection, so (WAL) no read ever delays a step's
commit and no reader waits for another (issue 15: the API's exports and the end-of-run summary
never share a lock).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sqlite3
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from config import redact_secrets
from daemon.analysis import RunSteps, steps_from_rows
from daemon.storage.series import read_series
from daemon.storage.step_record import STEP_COLUMNS, STEPS_SCHEMA, StepRecord, column_type
from daemon.storage.step_text import CSV_HEADER, csv_lines
from daemon.storage.transaction import RecorderError, Transaction, claim

# StepRecord and STEP_COLUMNS (daemon/storage/step_record.py) are what this module records: exported
# with it
__all__ = [
    "DATABASE_NAME",
    "EXPORT_BATCH_STEPS",
    "INTERRUPTED",
    "LIVE_STATES",
    "LOCK_NAME",
    "STEP_COLUMNS",
    "Recorder",
    "RecorderError",
    "RunRow",
    "StepRecord",
    "read_steps",
    "step_rows",
]

logger = logging.getLogger(__name__)

DATABASE_NAME = "thermocomp.sqlite3"
LOCK_NAME = "thermocomp.lock"

#: Run states that mean "someone was still working on it": after a crash they become
#: ``interrupted`` (see daemon.run.states.RunState).
LIVE_STATES = ("starting", "running", "paused", "stopping", "fault")
INTERRUPTED = "interrupted"
#: Steps per batch of a Parquet export (one row group each).
EXPORT_BATCH_STEPS = 10_000


_RUNS_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    state TEXT NOT NULL,
    started_at REAL NOT NULL,          -- Unix time (s)
    ended_at REAL,
    parameters_json TEXT NOT NULL,     -- the run's parameters
    config_json TEXT NOT NULL,         -- the full effective settings
    network_json TEXT,                 -- the thermal network the controller used
    software_version TEXT NOT NULL,
    summary_json TEXT,                 -- Table 6.1 figures, at the end
    reason TEXT,                       -- why it paused/faulted/ended, if not normally
    kind TEXT                          -- its run kind's name (daemon/run/kinds.py)
)
"""

#: A run whose summary a shutdown gave up (its budget within TimeoutStopSec ran out): what the
#: summary needs that only the ending daemon's memory held (overruns, skipped deadlines, the
#: timing, the kind's own figures: daemon/run/summary.py), computed at the next start. The row
#: goes in the same transaction as the summary is written, so a second shutdown that gives the
#: summary up again keeps it. ``IF NOT EXISTS``: an older database gains the table at open.
_PENDING_SUMMARIES_SCHEMA = """
CREATE TABLE IF NOT EXISTS pending_summaries (
    run_id INTEGER PRIMARY KEY REFERENCES runs(id),
    basis_json TEXT NOT NULL,          -- daemon/run/summary.py SummaryBasis
    deferred_at REAL NOT NULL          -- Unix time (s)
)
"""


@dataclass(frozen=True, slots=True)
class RunRow:
    id: int
    state: str
    started_at: float
    ended_at: float | None
    parameters: dict[str, Any]
    config: dict[str, Any]
    network: dict[str, Any] | None
    software_version: str
    summary: dict[str, Any] | None
    reason: str | None
    step_count: int
    #: its summary was deferred by a shutdown and is computed at the next start
    summary_pending: bool = False
    #: its run kind's name (daemon/run/kinds.py); None: recorded before runs said their kind
    kind: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class Recorder:
    """The run database under ``data_dir``. Use as a context manager or call close()."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        self.path = self.data_dir / DATABASE_NAME
        self._lock = threading.Lock()  # the writing connection
        self._readers = threading.local()  # one reading connection per thread
        self._reader_list: list[sqlite3.Connection] = []  # all of them, to close
        self._readers_lock = threading.Lock()  # guards _reader_list and closing
        self._closed = False
        #: the latest write's failure (disk full, read-only...), None once a write succeeds:
        #: /health reports it (issue 26)
        self.write_error: str | None = None
        try:
            self.data_dir.mkdir(parents=True, exist_ok=True)
            self._owner = claim(self.data_dir / LOCK_NAME)
        except OSError as err:
            raise RecorderError(f"cannot open the run database {self.path}: {err}") from err
        try:
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        except sqlite3.Error as err:
            self._owner.close()
            raise RecorderError(f"cannot open the run database {self.path}: {err}") from err
        try:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.execute(_RUNS_SCHEMA)
            self._db.execute(STEPS_SCHEMA)
            self._db.execute(_PENDING_SUMMARIES_SCHEMA)
            self._add_missing_step_columns()
            self._add_run_kind_column()
            self._redact_stored_configs()
        except (sqlite3.Error, OSError) as err:
            self._db.close()
            self._owner.close()
            raise RecorderError(f"cannot open the run database {self.path}: {err}") from err
        self.interrupted_runs = self._mark_interrupted()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        with self._readers_lock:
            self._closed = True
            for reader in self._reader_list:
                reader.close()
            self._reader_list.clear()
        with self._lock:
            self._db.close()
            self._owner.close()  # releases the claim on the data directory

    def _add_missing_step_columns(self) -> None:
        """A database written by an older version lacks the newer (extra, nullable) columns:
        add them, so old runs stay readable and new steps can be written."""
        present = {row[1] for row in self._db.execute("PRAGMA table_info(steps)")}
        for field in dataclasses.fields(StepRecord):
            if field.name not in present:
                self._db.execute(f"ALTER TABLE steps ADD COLUMN {field.name} {column_type(field)}")
                logger.info("run database: added the steps column %s", field.name)

    def _add_run_kind_column(self) -> None:
        """A database written before runs recorded their kind (issue 27) gains the column; its
        older runs keep a null kind, which the API says as such rather than guess one from
        their parameters."""
        present = {row[1] for row in self._db.execute("PRAGMA table_info(runs)")}
        if "kind" not in present:
            self._db.execute("ALTER TABLE runs ADD COLUMN kind TEXT")
            logger.info("run database: added the runs column kind")

    def _redact_stored_configs(self) -> None:
        """Migration (issue 16): a database written before run rows were redacted holds the
        API tokens in clear in ``config_json``: redact them in place, once (a redacted row
        no longer matches the filter)."""
        rows = self._db.execute(
            "SELECT id, config_json FROM runs WHERE config_json LIKE '%token\"%'"
        ).fetchall()
        changed = []
        for run_id, text in rows:
            stored = json.loads(text)
            redacted = redact_secrets(stored)
            if redacted != stored:
                changed.append((_dumps(redacted), run_id))
        if changed:
            self._db.execute("BEGIN IMMEDIATE")
            self._db.executemany("UPDATE runs SET config_json = ? WHERE id = ?", changed)
            self._db.execute("COMMIT")
            logger.warning("run database: redacted the secrets stored in %d run(s)", len(changed))

    # --- writing -----------------------------------------------------------------------

    def _mark_interrupted(self) -> list[int]:
        """Mark runs a crash left in a live state as ``interrupted`` (their steps are kept)."""
        marks = ",".join("?" * len(LIVE_STATES))
        with self._write() as db:
            ids = [
                int(row[0])
                for row in db.execute(f"SELECT id FROM runs WHERE state IN ({marks})", LIVE_STATES)
            ]
            db.execute(
                f"UPDATE runs SET state = ?, reason = COALESCE(reason, ?) WHERE state IN ({marks})",
                (INTERRUPTED, "the daemon stopped without ending the run", *LIVE_STATES),
            )
        for run_id in ids:
            logger.warning("run %d was left unfinished by a crash: marked interrupted", run_id)
        return ids

    def create_run(
        self,
        parameters: Mapping[str, Any],
        config: Mapping[str, Any],
        network: Mapping[str, Any] | None,
        software_version: str,
        state: str = "starting",
        *,
        kind: str | None = None,
    ) -> int:
        """The run's row; ``kind``: its run kind's name (daemon/run/kinds.py)."""
        with self._write() as db:
            cursor = db.execute(
                "INSERT INTO runs (state, started_at, parameters_json, config_json, network_json,"
                " software_version, kind) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    state,
                    time.time(),
                    _dumps(parameters),
                    _dumps(redact_secrets(config)),  # tokens are never stored
                    None if network is None else _dumps(network),
                    software_version,
                    kind,
                ),
            )
            run_id = cursor.lastrowid
        assert run_id is not None
        return run_id

    def set_run_state(self, run_id: int, state: str, reason: str | None = None) -> None:
        with self._write() as db:
            db.execute(
                "UPDATE runs SET state = ?, reason = ? WHERE id = ?", (state, reason, run_id)
            )

    def finish_run(
        self, run_id: int, state: str, summary: Mapping[str, Any] | None, reason: str | None
    ) -> None:
        with self._write() as db:
            db.execute(
                "UPDATE runs SET state = ?, ended_at = ?, summary_json = ?, reason = ? "
                "WHERE id = ?",
                (state, time.time(), None if summary is None else _dumps(summary), reason, run_id),
            )

    def write_step(self, record: StepRecord, *, replace: bool = False) -> None:
        """Insert one step and commit it (durably) before returning; ``replace``: rewrite the
        step's row written before (a followed run's measurement that finished after its step:
        daemon/run/followed/measure.py)."""
        values = dataclasses.astuple(record)
        placeholders = ",".join("?" * len(values))
        verb = "INSERT OR REPLACE" if replace else "INSERT"
        with self._write() as db:
            db.execute(
                f"{verb} INTO steps ({','.join(STEP_COLUMNS)}) VALUES ({placeholders})", values
            )

    def archive_frame(self, run_id: int, step: int, image: NDArray[np.integer]) -> str:
        """Save a frame as a lossless 16-bit PNG beside the database; return its path relative
        to the data directory (the step's ``frame_path``)."""
        import cv2  # here: `thermocomp run --help` must not load OpenCV

        relative = Path("frames") / f"run-{run_id:05d}" / f"step-{step:07d}.png"
        target = self.data_dir / relative
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            ok = cv2.imwrite(str(target), np.asarray(image, dtype=np.uint16))
        except (OSError, cv2.error) as err:
            raise RecorderError(f"cannot archive frame {target}: {err}") from err
        if not ok:
            raise RecorderError(f"cannot archive frame {target}")
        return relative.as_posix()

    # --- reading -----------------------------------------------------------------------

    def runs(self, limit: int = 50, offset: int = 0) -> list[RunRow]:
        """Runs, newest first."""
        with self._read() as db:
            rows = db.execute(
                f"{_RUN_SELECT} ORDER BY r.id DESC LIMIT ? OFFSET ?", (limit, offset)
            ).fetchall()
        return [_run_row(row) for row in rows]

    def run(self, run_id: int) -> RunRow | None:
        with self._read() as db:
            row = db.execute(f"{_RUN_SELECT} WHERE r.id = ?", (run_id,)).fetchone()
        return None if row is None else _run_row(row)

    def steps(self, run_id: int, start: int = 0, limit: int | None = None) -> list[StepRecord]:
        """Steps of a run in order, from step number ``start``."""
        with self._read() as db:
            return read_steps(db, run_id, start, limit)

    def run_steps(self, run_id: int, columns: Sequence[str] = STEP_COLUMNS) -> RunSteps:
        """The run's steps as series (daemon.analysis.RunSteps), streamed from the database:
        never the whole run as records in memory (an hour at a 20 ms step is 180,000 steps).
        ``columns`` limits what is read (the JSON columns cost the most to parse)."""
        with self._read() as db:
            return steps_from_rows(step_rows(db, run_id, columns))

    def run_series(
        self,
        run_id: int,
        columns: Sequence[str] = STEP_COLUMNS,
        abandon: threading.Event | None = None,
    ) -> RunSteps:
        """The run's numeric steps, flags and errors as columns read chunk by chunk
        (daemon/storage/series.py: the end of a 24-h run); ``abandon`` gives the read up."""
        with self._read() as db:
            return read_series(db, run_id, columns, abandon)

    def set_summary(self, run_id: int, summary: Mapping[str, Any] | None) -> None:
        """The summary of a run whose end is recorded already (it is written after it); a
        deferred one is no longer pending (same transaction)."""
        with self._write() as db:
            db.execute(
                "UPDATE runs SET summary_json = ? WHERE id = ?",
                (None if summary is None else _dumps(summary), run_id),
            )
            db.execute("DELETE FROM pending_summaries WHERE run_id = ?", (run_id,))

    def defer_summary(self, run_id: int, basis: Mapping[str, Any]) -> None:
        """Keep what a run's summary needs beyond its steps, to compute it at the next start
        (a shutdown gave it up). A second deferral of the same run replaces the first."""
        with self._write() as db:
            db.execute(
                "INSERT OR REPLACE INTO pending_summaries (run_id, basis_json, deferred_at) "
                "VALUES (?, ?, ?)",
                (run_id, _dumps(basis), time.time()),
            )

    def pending_summaries(self) -> list[tuple[int, dict[str, Any]]]:
        """The deferred summaries' run ids and bases, oldest run first."""
        with self._read() as db:
            rows = db.execute(
                "SELECT run_id, basis_json FROM pending_summaries ORDER BY run_id"
            ).fetchall()
        return [(int(run_id), json.loads(text)) for run_id, text in rows]

    def arm_poses(self, run_id: int) -> list[str | None]:
        """The measured pose of each step of an arm run, in step order (None: a two-link
        run's step)."""
        with self._read() as db:
            rows = db.execute(
                "SELECT arm_pose FROM steps WHERE run_id = ? ORDER BY step", (run_id,)
            ).fetchall()
        return [row[0] for row in rows]

    def export_csv(self, run_id: int, path: Path | None = None) -> str:
        """The run's steps as CSV (header = STEP_COLUMNS, empty cell = missing); written to
        ``path`` when given. Returns the text."""
        with self._read() as db:
            text = CSV_HEADER + "\n" + csv_lines(db, run_id, 0, None)[0].decode()
        if path is not None:
            Path(path).write_text(text, encoding="utf-8")
        return text

    def export_parquet(self, run_id: int, path: Path) -> None:
        """The run's steps as Parquet; needs the optional ``pyarrow`` (extra ``parquet``)."""
        try:
            import pyarrow as pa  # type: ignore[import-untyped, import-not-found, unused-ignore]
            import pyarrow.parquet as pq  # type: ignore[import-untyped, import-not-found, unused-ignore]
        except ImportError as err:
            raise RecorderError(
                "Parquet export needs pyarrow: pip install 'thermocomp[parquet]'"
            ) from err
        # batch by batch, with the schema of the table's column types (a column that is all
        # null in one batch keeps its type): memory is one batch whatever the run's length
        arrow_types = {"INTEGER": pa.int64(), "REAL": pa.float64(), "TEXT": pa.string()}
        schema = pa.schema(
            [(f.name, arrow_types[column_type(f)]) for f in dataclasses.fields(StepRecord)]
        )
        with self._read() as db, pq.ParquetWriter(str(path), schema) as writer:
            cursor = db.execute(
                f"SELECT {','.join(STEP_COLUMNS)} FROM steps WHERE run_id = ? ORDER BY step",
                (run_id,),
            )
            while batch := cursor.fetchmany(EXPORT_BATCH_STEPS):
                columns = [list(column) for column in zip(*batch, strict=True)]
                writer.write_table(pa.table(columns, schema=schema))

    # --- internals -----------------------------------------------------------------------

    def _write(self) -> Transaction:
        return Transaction(self._db, self._lock, self.path, on_write=self._note_write)

    def _note_write(self, error: str | None) -> None:
        self.write_error = error

    def _read(self) -> Transaction:
        """A read snapshot on this thread's own query-only connection: in WAL mode a reader
        never blocks the writer nor another reader."""
        reader: tuple[sqlite3.Connection, threading.Lock] | None = getattr(
            self._readers, "connection", None
        )
        if reader is None:
            with self._readers_lock:
                if self._closed:
                    raise RecorderError(f"{self.path}: the run database is closed")
                try:
                    db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
                    db.execute("PRAGMA query_only=ON")
                except sqlite3.Error as err:
                    raise RecorderError(f"cannot read the run database {self.path}: {err}") from err
                self._reader_list.append(db)
            reader = (db, threading.Lock())  # the lock only pairs with Transaction's API
            self._readers.connection = reader
        return Transaction(reader[0], reader[1], self.path, begin="BEGIN")


def read_steps(
    db: sqlite3.Connection, run_id: int, start: int = 0, limit: int | None = None
) -> list[StepRecord]:
    """Steps of a run in order, from step number ``start``, at most ``limit``."""
    rows = db.execute(
        f"SELECT {','.join(STEP_COLUMNS)} FROM steps WHERE run_id = ? AND step >= ? "
        "ORDER BY step LIMIT ?",
        (run_id, start, -1 if limit is None else limit),
    ).fetchall()
    return [StepRecord(*row) for row in rows]


def step_rows(
    db: sqlite3.Connection, run_id: int, columns: Sequence[str] = STEP_COLUMNS
) -> Iterator[dict[str, Any]]:
    """A run's steps in order as column -> value mappings, one row at a time (a cursor)."""
    unknown = set(columns) - set(STEP_COLUMNS)
    if unknown:  # the names go into the SQL text: only the schema's own
        raise ValueError(f"not step columns: {sorted(unknown)}")
    cursor = db.execute(
        f"SELECT {','.join(columns)} FROM steps WHERE run_id = ? ORDER BY step", (run_id,)
    )
    for row in cursor:
        yield dict(zip(columns, row, strict=True))


_RUN_SELECT = (
    "SELECT r.id, r.state, r.started_at, r.ended_at, r.parameters_json, r.config_json, "
    "r.network_json, r.software_version, r.summary_json, r.reason, "
    "(SELECT COUNT(*) FROM steps s WHERE s.run_id = r.id), "
    "EXISTS (SELECT 1 FROM pending_summaries p WHERE p.run_id = r.id), r.kind FROM runs r"
)


def _run_row(row: Sequence[Any]) -> RunRow:
    return RunRow(
        id=row[0],
        state=row[1],
        started_at=row[2],
        ended_at=row[3],
        parameters=json.loads(row[4]),
        config=json.loads(row[5]),
        network=None if row[6] is None else json.loads(row[6]),
        software_version=row[7],
        summary=None if row[8] is None else json.loads(row[8]),
        reason=row[9],
        step_count=row[10],
        summary_pending=bool(row[11]),
        kind=row[12],
    )


def _dumps(value: Mapping[str, Any]) -> str:
    return json.dumps(value, default=str, allow_nan=True)
