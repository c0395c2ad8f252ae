"""Issue 26: every stopping path holds first, and the end of a long run fits in systemd's
TimeoutStopSec. The end (final state) is committed before the summary; a shutdown gives the
summary up rather than the end; the summary reads a run's steps as columns, chunk by chunk,
with the same values as the row-by-row reader."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
import time
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.run_database import add_steps
from daemon import service as service_module
from daemon.analysis import NUMERIC_COLUMNS
from daemon.run.states import RunState
from daemon.run.two_link.kind import TwoLinkKind
from daemon.storage.recorder import DATABASE_NAME, Recorder
from daemon.storage.series import SummaryAbandonedError, read_series
from tests.fakes import Harness, make_settings, params

WAIT_S = 60.0


def test_the_columnar_reader_reads_what_the_row_reader_reads(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({"step_s": 0.02}, {}, None, "test")
    add_steps(tmp_path, run_id, 1234)
    with closing(sqlite3.connect(tmp_path / DATABASE_NAME)) as db, db:
        db.execute("UPDATE steps SET residual_um = NULL, flags = 'late,robot-error' WHERE step = 7")
        db.execute("UPDATE steps SET error = 'robot: gone' WHERE step = 9")
    with Recorder(tmp_path) as recorder:
        rows = recorder.run_steps(run_id, (*NUMERIC_COLUMNS, "run_id", "flags", "error"))
        columns = recorder.run_series(run_id, (*NUMERIC_COLUMNS, "run_id", "flags", "error"))
    assert columns.n_steps == rows.n_steps == 1234
    assert columns.run_id == rows.run_id
    assert set(columns.numeric) == set(rows.numeric)
    for name, values in rows.numeric.items():
        np.testing.assert_array_equal(columns.numeric[name], values, err_msg=name)
    assert columns.flags == rows.flags and columns.flags[7] == ("late", "robot-error")
    assert columns.errors == rows.errors and columns.errors[9] == "robot: gone"
    assert np.isnan(columns.numeric["residual_um"][7])


def test_the_columnar_reader_can_be_abandoned(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({"step_s": 0.02}, {}, None, "test")
    add_steps(tmp_path, run_id, 10)
    abandon = threading.Event()
    abandon.set()
    with (
        closing(sqlite3.connect(tmp_path / DATABASE_NAME)) as db,
        pytest.raises(SummaryAbandonedError),
    ):
        read_series(db, run_id, NUMERIC_COLUMNS, abandon)


async def test_a_runs_end_is_committed_before_its_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A day at 20 ms is 4.32 M steps to read back for the summary: the final state must not
    wait for it."""
    release = threading.Event()
    summarize = TwoLinkKind.summary

    def slow_summary(*args: Any, **kwargs: Any) -> dict[str, Any]:
        release.wait(WAIT_S)
        return summarize(*args, **kwargs)

    monkeypatch.setattr(TwoLinkKind, "summary", slow_summary)
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        stop = asyncio.create_task(daemon.stop())
        assert daemon.recorder is not None
        recorder = daemon.recorder
        row = await _until_ended(daemon, recorder, info["id"])
        assert row.summary is None and harness.robot.held  # ended, held, summary to come
        release.set()
        final = await stop
        assert final["state"] == "stopped"
        row = await daemon.read(recorder.run, info["id"])
        assert row is not None and row.summary is not None and "steps" in row.summary


@pytest.mark.slow
async def test_a_shutdown_gives_up_a_summary_it_cannot_wait_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    started = threading.Event()

    def endless_summary(*args: Any, abandon: threading.Event, **kwargs: Any) -> dict[str, Any]:
        started.set()
        while not abandon.wait(0.01):  # as the chunked reader: checks between chunks
            pass
        raise SummaryAbandonedError("abandoned")

    monkeypatch.setattr(TwoLinkKind, "summary", endless_summary)
    monkeypatch.setattr(service_module, "SHUTDOWN_SUMMARY_BUDGET_S", 0.2)
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        began = time.monotonic()
        await asyncio.wait_for(daemon.shutdown(), WAIT_S)
        took_s = time.monotonic() - began
        assert started.is_set() and harness.robot.held
        assert daemon.recorder is not None
        row = await daemon.read(daemon.recorder.run, info["id"])
    assert row is not None and row.state == "stopped" and row.reason == "daemon shut down"
    assert row.summary is None
    assert took_s < settings.scheduler.stop_grace_s + 0.2 + 10.0  # not waiting for it


async def _until_ended(daemon: Any, recorder: Recorder, run_id: int) -> Any:
    """Poll the database (it has no event to await) until the run's end is recorded."""
    async with asyncio.timeout(WAIT_S):
        while True:
            row = await daemon.read(recorder.run, run_id)
            if row is not None and row.state == "stopped":
                return row
            await asyncio.sleep(0.01)
