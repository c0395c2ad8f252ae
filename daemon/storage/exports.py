"""Step exports, encoded in worker processes (issue 15: heavy reads never delay a step).

Encoding tens of thousands of steps as JSON or CSV is seconds of CPU, much of it in C calls that
hold the GIL throughout: done by a thread of the daemon's own process it would stall the
control loop for as long (measured: p99 step lateness 0.8 ms -> 270 ms with six exporting
clients, benchmarks/bench_control_core.py). So each chunk of an export is read and encoded
here, in a child process with its own read-only connection, and comes back as bytes of
bounded size (``CHUNK_STEPS`` steps) that the API streams out while the next chunk is
encoded. The encoding itself is daemon/storage/step_text.py's (SQLite quotes; numbers printed
by msgspec's C encoder in repr's layout, a column at a time; issue 30: at the storage's speed).

Everything here is a plain function of picklable arguments: ``daemon.run.workers.Workers.export``
runs it in its process pool.
"""

from __future__ import annotations

import dataclasses
import sqlite3
from contextlib import closing
from pathlib import Path

from daemon.storage.step_text import CSV_HEADER, csv_lines, json_objects

#: Steps per chunk: ~1.2 kB of CSV and ~2.2 kB of JSON a step on a bench run, so 2-5 MB a
#: chunk (a short copy for the daemon to receive; at most two in the daemon at once, one
#: being sent and one arriving) and some tens of milliseconds of a worker's time, against a
#: millisecond of fixed cost per chunk (connection, query, hand-over).
CHUNK_STEPS = 2_000


@dataclasses.dataclass(frozen=True, slots=True)
class Chunk:
    data: bytes  # the encoded steps: JSON objects separated by commas, or CSV rows
    count: int  # steps in it
    next_start: int | None  # the next chunk's first step, None at the end of the run


def json_chunk(database: Path, run_id: int, start: int, count: int) -> Chunk:
    """Up to ``count`` steps from step ``start`` as JSON objects joined by commas (no
    brackets: the caller frames them); non-finite numbers as null."""
    return _chunk(database, run_id, start, count, json=True, header=False)


def csv_chunk(database: Path, run_id: int, start: int, count: int, header: bool) -> Chunk:
    """Up to ``count`` steps from step ``start`` as CSV rows (header = STEP_COLUMNS when
    ``header``; empty cell = missing; floats with all their digits)."""
    return _chunk(database, run_id, start, count, json=False, header=header)


def _chunk(
    database: Path, run_id: int, start: int, count: int, *, json: bool, header: bool
) -> Chunk:
    uri = f"{Path(database).resolve().as_uri()}?mode=ro"
    with closing(sqlite3.connect(uri, uri=True)) as db:
        db.execute("BEGIN")  # one snapshot for the chunk
        encode = json_objects if json else csv_lines
        data, found, last = encode(db, run_id, start, count)
    if header:
        data = f"{CSV_HEADER}\n".encode() + data
    following = None if found < count or last is None else last + 1
    return Chunk(data, found, following)
