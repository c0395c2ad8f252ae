"""Issue 26, the smaller promises around a run's end: ``wait_run`` never raises CancelledError
into a caller nobody cancelled; ``/health`` reports the run database (a failing write is not
``ok``); an ended run without a report gets it written on demand; after a storage failure
aborted a run, the robot's hold says so (not "stopped by request"); pause and stop hold the
robot before anything else, the stop even when the database cannot answer."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from api.app import create_app
from daemon.run.states import RunState
from tests.fakes import Harness, make_settings, params
from tests.test_api_server import serve
from tests.test_control_core import CONTROL_HEADERS, api_settings

WAIT_S = 60.0
DAY_S = 86_400.0


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[tuple[Harness, httpx.AsyncClient]]:
    # a day's run: none ends by itself during a test. With a 60-s run the virtual clock ran it
    # to its end while a stop waited for the stuck database below, and its end held the robot:
    # the stop test passed on the code that read the database before holding (3b82f76)
    day = {"step_s": 0.2, "duration_s": DAY_S}
    settings = api_settings(make_settings(tmp_path, scheduler=day))
    harness = Harness(settings)
    app = create_app(settings, service_factory=lambda _settings: harness.daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=WAIT_S) as client,
    ):
        yield harness, client


async def test_wait_run_never_raises_cancelled_error_into_its_caller(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        waiting = asyncio.create_task(daemon.wait_run())
        await asyncio.sleep(0)
        session = daemon._session
        assert session is not None and session.task is not None
        session.task.cancel()  # as a stop that abandons a step stuck on a device does
        info = await asyncio.wait_for(waiting, WAIT_S)  # no CancelledError here
        assert info["state"] == "aborted"


async def test_health_reports_a_failing_database(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api
    healthy = (await client.get("/api/v1/health")).json()
    assert healthy["status"] == "ok" and healthy["storage"] == "ok"
    recorder = harness.daemon.recorder
    assert recorder is not None
    recorder._db.execute("PRAGMA query_only = 1")  # the disk turned read-only
    try:
        started = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
        assert started.status_code == 503
        health = (await client.get("/api/v1/health")).json()
        assert health["status"] == "degraded" and health["storage"].startswith("failing: ")
    finally:
        recorder._db.execute("PRAGMA query_only = 0")
    started = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
    assert started.status_code == 201  # a write succeeded: healthy again
    assert (await client.get("/api/v1/health")).json()["storage"] == "ok"
    await client.post(f"/api/v1/runs/{started.json()['id']}/stop", headers=CONTROL_HEADERS)


@pytest.mark.slow
async def test_an_ended_run_without_a_report_gets_one_on_demand(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api  # storage.report_at_end is off: no report was written
    run = (await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)).json()
    async with asyncio.timeout(WAIT_S):
        while harness.daemon.run is None or harness.daemon.run.step < 1:  # noqa: ASYNC110
            await asyncio.sleep(0.01)
    await client.post(f"/api/v1/runs/{run['id']}/stop", headers=CONTROL_HEADERS)
    report = await client.get(f"/api/v1/runs/{run['id']}/report")
    assert report.status_code == 202 and report.json()["kind"] == "pending"
    async with asyncio.timeout(120.0):
        while report.status_code == 202:
            await asyncio.sleep(0.2)
            report = await client.get(f"/api/v1/runs/{run['id']}/report")
    assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")


async def test_a_storage_abort_says_so_in_the_robots_hold(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api
    run = (await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)).json()
    daemon = harness.daemon
    async with asyncio.timeout(WAIT_S):
        while daemon.run is None or daemon.run.step < 1:  # noqa: ASYNC110
            await asyncio.sleep(0.01)
    assert daemon.recorder is not None
    daemon.recorder._db.execute("PRAGMA query_only = 1")  # the next step cannot be recorded
    try:
        info = await daemon.wait_run()
    finally:
        daemon.recorder._db.execute("PRAGMA query_only = 0")
    assert info["id"] == run["id"] and info["state"] == "aborted"
    robot = (await client.get("/api/v1/state")).json()["robot"]
    assert robot["motion_held"]
    assert robot["hold_reason"] != "stopped by request"
    assert "aborted" in robot["hold_reason"] and "recording failed" in robot["hold_reason"]


@pytest.mark.parametrize(("action", "final"), [("stop", "stopped"), ("pause", "paused")])
async def test_a_stop_holds_before_the_database_answers(
    api: tuple[Harness, httpx.AsyncClient], action: str, final: str
) -> None:
    """The database is stuck (a 4.32 M-step COUNT, a slow disk): the stop (or pause) holds
    first."""
    harness, client = api
    run = (await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)).json()
    daemon = harness.daemon
    async with asyncio.timeout(WAIT_S):
        while daemon.run is None or daemon.run.step < 1:  # noqa: ASYNC110
            await asyncio.sleep(0.01)
    stuck = threading.Event()
    read = daemon.read

    async def stuck_read(*args: object) -> object:
        await asyncio.to_thread(stuck.wait, WAIT_S)
        return await read(*args)  # type: ignore[arg-type]

    daemon.read = stuck_read  # type: ignore[method-assign]
    stop = asyncio.create_task(
        client.post(f"/api/v1/runs/{run['id']}/{action}", headers=CONTROL_HEADERS)
    )
    async with asyncio.timeout(WAIT_S):
        while not harness.robot.held:  # noqa: ASYNC110 -- the permit has no event
            await asyncio.sleep(0.005)
    assert not stop.done()  # held while the database still has not answered
    stuck.set()
    stopped = await stop
    assert stopped.status_code == 200
    assert stopped.json()["state"] == final  # by the request, not by reaching the run's end
    if action == "pause":
        await client.post(f"/api/v1/runs/{run['id']}/stop", headers=CONTROL_HEADERS)
