"""Step exports, encoded in worker processes (issue 15: heavy reads never delay a step).

Encoding tens of thousands of steps as JSON or CSV is seconds of CPU, much of it in C calls that
hold the GIL throughout (``json.dumps`` of a page): done by a thread of the daemon's own process
it would stall the control loop for as long (measured: p99 step lateness 0.8 ms -> 270 ms with
six exporting clients, benchmarks/bench_control_core.py). So each chunk of an export is read and
encoded here, in a child process with its own read-only connection, and comes back as bytes of
bounded size (``CHUNK_STEPS`` steps, about 1 MB) that the API streams out.

Everything here is a plain function of picklable arguments: ``daemon.run.workers.Workers.export``
runs it in its process pool.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Any

from daemon.storage.recorder import read_steps, write_steps_csv

#: Steps per chunk: about 0.9 kB of JSON a step, so ~1 MB a chunk (a short copy for the
#: daemon to receive) and a few tens of milliseconds of a worker's time.
CHUNK_STEPS = 1_000


@dataclasses.dataclass(frozen=True, slots=True)
class Chunk:
    data: bytes  # the encoded steps: JSON objects separated by commas, or CSV rows
    count: int  # steps in it
    next_start: int | None  # the next chunk's first step, None at the end of the run


def json_chunk(database: Path, run_id: int, start: int, count: int) -> Chunk:
    """Up to ``count`` steps from step ``start`` as JSON objects joined by commas (no
    brackets: the caller frames them); non-finite numbers as null."""
    records = _read(database, run_id, start, count)
    data = ",".join(
        json.dumps(_finite(dataclasses.asdict(r)), separators=(",", ":")) for r in records
    ).encode()
    return Chunk(data, len(records), _next(records, count))


def csv_chunk(database: Path, run_id: int, start: int, count: int, header: bool) -> Chunk:
    """Up to ``count`` steps from step ``start`` as CSV rows (header = STEP_COLUMNS when
    ``header``; empty cell = missing; floats with all their digits)."""
    records = _read(database, run_id, start, count)
    buffer = io.StringIO()
    write_steps_csv(records, buffer)
    text = buffer.getvalue() if header else buffer.getvalue().split("\n", 1)[1]
    return Chunk(text.encode(), len(records), _next(records, count))


def _read(database: Path, run_id: int, start: int, count: int) -> list[Any]:
    uri = f"{Path(database).resolve().as_uri()}?mode=ro"
    with closing(sqlite3.connect(uri, uri=True)) as db:
        db.execute("BEGIN")  # one snapshot for the chunk
        return read_steps(db, run_id, start, count)


def _next(records: list[Any], count: int) -> int | None:
    return int(records[-1].step) + 1 if len(records) == count else None


def _finite(values: dict[str, Any]) -> dict[str, Any]:
    return {
        k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in values.items()
    }
