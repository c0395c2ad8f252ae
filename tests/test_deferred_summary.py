"""A summary a shutdown gives up is deferred, not lost: what only the ending daemon's memory
held (overruns, skipped deadlines, the timing, the kind's figures) is kept with the run, and the
next start computes the summary an unabandoned end would have written; a second shutdown
during that computation keeps it pending. Real recorder, SQLite in tmp_path; the shutdown's
summary budget (daemon/service.py) is what forces the abandonment."""

from __future__ import annotations

import asyncio
import json
import logging
import sqlite3
import threading
from collections.abc import Callable
from contextlib import closing
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.app import create_app
from api.routers.runs import run_info
from daemon import service as service_module
from daemon.run import pending_summaries as pending_module
from daemon.run.kinds import summary_from_basis
from daemon.run.states import RunState
from daemon.run.two_link.kind import TwoLinkKind
from daemon.run.workers import READ_THREADS
from daemon.storage.recorder import DATABASE_NAME, Recorder
from tests.fakes import Harness, make_settings, params
from tests.test_api_server import CONTROL, READ, serve

WAIT_S = 60.0
#: how long the API read threads may take to be all running at once (a loaded machine)
READ_BARRIER_S = 10.0


async def _until(condition: Callable[[], bool]) -> None:
    async with asyncio.timeout(WAIT_S):
        while not condition():  # noqa: ASYNC110 -- the conditions are plain attributes
            await asyncio.sleep(0.005)


def _canonical(summary: Any) -> str:
    """As the recorder stores it (NaN included), keys sorted: equal text, equal summary."""
    return json.dumps(summary, sort_keys=True, default=str, allow_nan=True)


async def _end_by_shutdown_without_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> tuple[int, dict[str, Any]]:
    """A run ended by a shutdown whose summary budget runs out: returns its id and the
    summary the end would have written had it had the time (computed from the same basis,
    before the abandonment, with the kind's real summary)."""
    real_summary = TwoLinkKind.summary
    expected: dict[str, Any] = {}
    started = threading.Event()

    def summary_that_outlasts_the_budget(
        kind: TwoLinkKind, recorder: Recorder, basis: dict[str, Any], *, abandon: threading.Event
    ) -> dict[str, Any]:
        expected.update(real_summary(kind, recorder, basis, abandon=None))
        started.set()
        abandon.wait(WAIT_S)  # as a 4.32 M-step read: longer than the budget
        return real_summary(kind, recorder, basis, abandon=abandon)  # gives up at a chunk

    monkeypatch.setattr(TwoLinkKind, "summary", summary_that_outlasts_the_budget)
    monkeypatch.setattr(service_module, "SHUTDOWN_SUMMARY_BUDGET_S", 0.2)
    settings = make_settings(tmp_path, scheduler={"stop_grace_s": 0.5})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        await _until(lambda: daemon.run is not None and daemon.run.step >= 3)  # a few steps
        await asyncio.wait_for(daemon.shutdown(), WAIT_S)
        assert started.is_set() and harness.robot.held
    monkeypatch.setattr(TwoLinkKind, "summary", real_summary)
    return info["id"], expected


async def test_a_summary_given_up_at_shutdown_is_computed_at_the_next_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    run_id, expected = await _end_by_shutdown_without_summary(tmp_path, monkeypatch)
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith(f"run {run_id}")]
    deferred = [message for message in said if "summary" in message]  # one line, no other
    assert deferred == [
        f"run {run_id}: summary deferred to the next start (the stop's budget ran out)"
    ]
    assert expected["steps"] >= 3 and "timing" in expected and "overruns" in expected

    with Recorder(tmp_path) as recorder:  # the end is recorded; the summary is pending
        row = recorder.run(run_id)
        pending = recorder.pending_summaries()
    assert row is not None and row.state == "stopped" and row.summary is None
    assert row.summary_pending and [run_id] == [pending_id for pending_id, _ in pending]

    settings = make_settings(tmp_path, scheduler={"stop_grace_s": 0.5})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.pending_summaries is not None and daemon.recorder is not None
        await asyncio.wait_for(daemon.pending_summaries.wait(), WAIT_S)
        row = await daemon.read(daemon.recorder.run, run_id)
        assert row is not None
        info = run_info(row, daemon)
    assert not row.summary_pending and not info.summary_pending
    assert row.summary is not None
    assert _canonical(row.summary) == _canonical(expected)  # the summary the end would write
    assert f"run {run_id}: deferred summary computed and recorded" in caplog.text


async def test_a_pending_summary_survives_a_second_shutdown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run_id, expected = await _end_by_shutdown_without_summary(tmp_path, monkeypatch)
    real = summary_from_basis
    began = threading.Event()

    def slow(recorder: Recorder, basis: dict[str, Any], abandon: threading.Event) -> Any:
        began.set()
        abandon.wait(WAIT_S)
        return real(recorder, basis, abandon)  # gives up at its first chunk

    monkeypatch.setattr(pending_module, "summary_from_basis", slow)
    settings = make_settings(tmp_path, scheduler={"stop_grace_s": 0.5})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        await _until(began.is_set)
        # the daemon is ready and holds while the deferred summary is being read
        await daemon.hold_robot()
        assert harness.robot.held
    with Recorder(tmp_path) as recorder:
        row = recorder.run(run_id)
        assert [run_id] == [pending_id for pending_id, _ in recorder.pending_summaries()]
    assert row is not None and row.summary is None and row.summary_pending

    monkeypatch.setattr(pending_module, "summary_from_basis", real)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.pending_summaries is not None and daemon.recorder is not None
        await asyncio.wait_for(daemon.pending_summaries.wait(), WAIT_S)
        row = await daemon.read(daemon.recorder.run, run_id)
    assert row is not None and row.summary is not None and not row.summary_pending
    assert _canonical(row.summary) == _canonical(expected)


def test_an_older_database_gains_the_pending_table(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({"step_s": 0.02}, {}, None, "test")
    with closing(sqlite3.connect(tmp_path / DATABASE_NAME)) as db, db:
        db.execute("DROP TABLE pending_summaries")  # as written before it existed
    with Recorder(tmp_path) as recorder:
        row = recorder.run(run_id)
        assert row is not None and not row.summary_pending
        recorder.defer_summary(run_id, {"kind": "followed", "run_id": run_id, "fixed": {}})
        recorder.defer_summary(run_id, {"kind": "followed", "run_id": run_id, "fixed": {"a": 1}})
        assert recorder.pending_summaries() == [
            (run_id, {"kind": "followed", "run_id": run_id, "fixed": {"a": 1}})
        ]  # a second deferral replaces the first
        row = recorder.run(run_id)
        assert row is not None and row.summary_pending
        recorder.set_summary(run_id, {"a": 1})  # the summary and the end of pending: one commit
        assert recorder.pending_summaries() == []
        row = recorder.run(run_id)
        assert row is not None and row.summary == {"a": 1} and not row.summary_pending


async def test_api_reads_are_served_while_a_deferred_summary_computes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The deferred summary has its own thread (daemon/run/workers.py ``summary``): while one
    computes (here: blocked until the test lets it go), every API read thread is free --
    ``READ_THREADS`` reads that each need all of them at once complete -- and GET /runs
    answers through a real server. On the read pool (before) one of the two threads was the
    summary's: the barrier of two reads never filled."""
    with Recorder(tmp_path) as recorder:  # a run whose summary the last shutdown deferred
        run_id = recorder.create_run({"step_s": 1.0}, {}, None, "test")
        recorder.finish_run(run_id, "stopped", None, "shut down")
        recorder.defer_summary(
            run_id, {"kind": "followed", "run_id": run_id, "fixed": {"a": 1}, "after": {}}
        )
    real = summary_from_basis
    began, release = threading.Event(), threading.Event()
    threads: list[str] = []

    def blocking(recorder: Recorder, basis: dict[str, Any], abandon: threading.Event) -> Any:
        threads.append(threading.current_thread().name)
        began.set()
        release.wait(WAIT_S)
        return real(recorder, basis, abandon)

    monkeypatch.setattr(pending_module, "summary_from_basis", blocking)
    settings = make_settings(tmp_path, api={"control_token": CONTROL, "read_token": READ})
    harness = Harness(settings)
    app = create_app(settings, service_factory=lambda _settings: harness.daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=WAIT_S) as client,
    ):
        daemon = harness.daemon
        try:
            await asyncio.wait_for(asyncio.to_thread(began.wait, WAIT_S), WAIT_S)
            assert began.is_set()
            everyone = threading.Barrier(READ_THREADS, timeout=READ_BARRIER_S)
            await asyncio.wait_for(
                asyncio.gather(*(daemon.read(everyone.wait) for _ in range(READ_THREADS))),
                2 * READ_BARRIER_S,
            )
            listed = await client.get("/api/v1/runs", headers={"Authorization": f"Bearer {READ}"})
            assert listed.status_code == 200, listed.text
            (row,) = [r for r in listed.json()["runs"] if r["id"] == run_id]
            assert row["summary_pending"] is True and not release.is_set()
        finally:
            release.set()  # the summary goes on, whatever failed: the shutdown waits for it
        assert daemon.pending_summaries is not None and daemon.recorder is not None
        await asyncio.wait_for(daemon.pending_summaries.wait(), WAIT_S)
        stored = await daemon.read(daemon.recorder.run, run_id)
    assert stored is not None and stored.summary == {"a": 1} and not stored.summary_pending
    assert [name.split("_")[0] for name in threads] == ["deferred-summary"]
