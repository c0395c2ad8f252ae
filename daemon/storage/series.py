"""A run's numeric steps read as columns, chunk by chunk (issue 26: the end of a 24-h run).

The row-by-row reader (daemon.analysis.steps.steps_from_rows) makes a dict per step and
converts each cell in Python: ~15 us a step idle, 76 us at load 19, so the 4.32 M steps of a
day at 20 ms took minutes -- beyond systemd's TimeoutStopSec. Here SQLite hands over chunks of
rows and numpy converts each chunk at once (``None`` becomes NaN under ``dtype=float``); the
flags and errors, almost always empty, are read in a second pass and shared. Between chunks
an ``abandon`` event is checked: a shutdown that cannot wait gives up the summary, never the
run's end (daemon/run/session.py writes the end first).
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Sequence

import numpy as np

from daemon.analysis import NUMERIC_COLUMNS, RunSteps
from daemon.analysis.steps import FloatArray

#: Rows per chunk: a few MB of Python objects at a time.
CHUNK_ROWS = 50_000


class SummaryAbandonedError(Exception):
    """The read was given up (the daemon shuts down)."""


def read_series(
    db: sqlite3.Connection,
    run_id: int,
    columns: Sequence[str] = NUMERIC_COLUMNS,
    abandon: threading.Event | None = None,
) -> RunSteps:
    """The run's steps in step order as numeric columns (only those of ``columns`` that are
    numeric), with their flags and errors; no JSON column."""
    numeric = [name for name in NUMERIC_COLUMNS if name in columns]
    chunks: list[FloatArray] = []
    cursor = db.execute(
        f"SELECT {','.join(numeric)} FROM steps WHERE run_id = ? ORDER BY step", (run_id,)
    )
    while rows := cursor.fetchmany(CHUNK_ROWS):
        _check(abandon)
        chunks.append(np.array(rows, dtype=np.float64).reshape(len(rows), len(numeric)))
    table = np.concatenate(chunks) if chunks else np.empty((0, len(numeric)))
    shared: dict[str, tuple[str, ...]] = {"": ()}
    flags: list[tuple[str, ...]] = []
    errors: list[str] = []
    cursor = db.execute("SELECT flags, error FROM steps WHERE run_id = ? ORDER BY step", (run_id,))
    while rows := cursor.fetchmany(CHUNK_ROWS):
        _check(abandon)
        for cell, error in rows:
            text = cell or ""
            step_flags = shared.get(text)
            if step_flags is None:
                step_flags = shared[text] = tuple(f.strip() for f in text.split(",") if f.strip())
            flags.append(step_flags)
            errors.append(error or "")
    return RunSteps(
        run_id=str(run_id) if flags else None,
        numeric={name: np.ascontiguousarray(table[:, i]) for i, name in enumerate(numeric)},
        flags=tuple(flags),
        errors=tuple(errors),
    )


def _check(abandon: threading.Event | None) -> None:
    if abandon is not None and abandon.is_set():
        raise SummaryAbandonedError("the summary was abandoned: the daemon shuts down")
