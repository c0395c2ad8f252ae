"""Issue 15: the control core against the operator, the API, shutdown and storage.

One regression test per finding of the issue (the serial link's cancel-safety, point 4, is in
tests/test_c500c_link.py), through the daemon and, where the finding was made through it,
through a real uvicorn server. Synchronisation is by gates the fake devices wait at
(tests/fakes.py) and by the daemon's own events, never by sleeping.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import signal
import subprocess
import threading
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.app import create_app
from config import Settings
from daemon import service as service_module
from daemon.run.scheduler import FixedStepTimer
from daemon.run.states import RunState
from daemon.run.two_link import measure as measure_module
from daemon.run.two_link.kind import TwoLinkKind
from daemon.run.two_link.step import StepPipeline
from daemon.service import Daemon, ResumeRefusedError
from daemon.storage.recorder import Recorder, RecorderError, StepRecord
from drivers.clock import VirtualClock
from drivers.errors import DeviceError, GoalLostError
from tests.fakes import Gate, Harness, make_settings, params
from tests.helpers import REPO_ROOT, cli_command, free_port
from tests.test_api_server import CONTROL, serve

SIM = str(REPO_ROOT / "config" / "sim.toml")

CONTROL_HEADERS = {"Authorization": f"Bearer {CONTROL}"}
WAIT_S = 60.0  # bound of every wait below: a hang fails, never blocks the suite (30 s: a
# server start and a run's first step took longer at load 19 with the suite on both cores)


async def until(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
    """Yield to the loop until ``condition()`` holds (bounded)."""
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 -- the conditions are plain attributes
            await asyncio.sleep(0.001)


async def step_recorded(daemon: Daemon, step: int) -> None:
    await until(lambda: daemon.run is not None and daemon.run.step >= step)


def api_settings(settings: Settings) -> Settings:
    return settings.model_copy(
        update={"api": settings.api.model_copy(update={"control_token": CONTROL})}
    )


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[tuple[Harness, httpx.AsyncClient]]:
    """A real uvicorn server over a daemon on the fake devices (sensor errors pause runs)."""
    settings = api_settings(make_settings(tmp_path, scheduler={"sensor_error_policy": "pause"}))
    harness = Harness(settings)
    app = create_app(settings, service_factory=lambda _settings: harness.daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=WAIT_S) as client,
    ):
        yield harness, client


# --- 1. a step that ends in its own pause after the operator paused or stopped ---------------


@pytest.mark.parametrize("request_kind", ["pause", "stop"])
async def test_a_step_pausing_itself_after_a_request_never_aborts_the_run(
    tmp_path: Path, request_kind: str
) -> None:
    settings = make_settings(tmp_path, scheduler={"sensor_error_policy": "pause"})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        gate = Gate()
        await daemon.start_run(params(settings))
        harness.camera.gates[3] = gate  # the grab of step 2 (grab 0 is the reference)
        async with asyncio.timeout(WAIT_S):
            await gate.reached.wait()  # step 2 waits for its frame
        stopping: asyncio.Task[dict[str, Any]] | None = None
        if request_kind == "pause":
            await daemon.pause()
        else:
            stopping = asyncio.create_task(daemon.stop())
            await until(lambda: daemon.run is not None and daemon.run.state is RunState.STOPPING)
        gate.open(DeviceError("camera", "frame lost"))  # the step now ends in its own pause
        await step_recorded(daemon, 2)
        view = daemon.run
        assert view is not None and view.last_record is not None
        assert "camera-error" in view.last_record["flags"]  # the verdict is on the step
        if stopping is None:
            assert (view.state, view.reason) == (RunState.PAUSED, "paused by request")
            await daemon.resume()
            await step_recorded(daemon, 3)
            final = await daemon.stop()
        else:
            final = await stopping
    assert (final["state"], final["reason"]) == ("stopped", "stopped by request")


async def test_a_paused_step_during_a_commit_wait_keeps_the_run_paused(tmp_path: Path) -> None:
    # a 1 um step limit with scale 10 refuses step 1's target (an unsafe-target pause)
    settings = make_settings(tmp_path, compensation={"max_step_change_mm": 0.001})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        recorder, committing, release = daemon.recorder, threading.Event(), threading.Event()
        write_step = recorder.write_step

        def slow_commit(record: StepRecord) -> None:
            if record.step == 1:
                committing.set()
                release.wait(WAIT_S)
            write_step(record)

        recorder.write_step = slow_commit  # type: ignore[method-assign]
        await daemon.start_run(params(settings, deformation_scale=10.0))
        await until(committing.is_set)
        await daemon.pause()
        release.set()
        await step_recorded(daemon, 1)
        view = daemon.run
        assert view is not None and view.last_record is not None
        assert view.last_record["flags"] == "unsafe-target"
        assert (view.state, view.reason) == (RunState.PAUSED, "paused by request")
        final = await daemon.stop()
    assert final["state"] == "stopped"


async def test_pause_during_a_step_through_the_server(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api
    gate = Gate()
    created = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
    assert created.status_code == 201
    run_id = created.json()["id"]
    harness.camera.gates[3] = gate
    async with asyncio.timeout(WAIT_S):
        await gate.reached.wait()
    paused = await client.post(f"/api/v1/runs/{run_id}/pause", headers=CONTROL_HEADERS)
    assert paused.status_code == 200 and paused.json()["state"] == "paused"
    gate.open(DeviceError("camera", "frame lost"))
    await step_recorded(harness.daemon, 2)
    state = (await client.get("/api/v1/state")).json()
    assert state["state"] == "paused" and state["run"]["reason"] == "paused by request"
    assert (await client.post(f"/api/v1/runs/{run_id}/resume", headers=CONTROL_HEADERS)).is_success
    stopped = await client.post(f"/api/v1/runs/{run_id}/stop", headers=CONTROL_HEADERS)
    assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"


# --- 2. a hold that holds ------------------------------------------------------------------


async def _queue_a_move_behind_a_pose_read(harness: Harness) -> tuple[Gate, asyncio.Task[Any]]:
    """Another command (as a resume, a teach or the reconnect task would) holds the driver's
    lock; the run's next move queues behind it."""
    gate = Gate()
    harness.robot.pose_gate = gate
    reader = asyncio.create_task(harness.robot.actual_pose())
    async with asyncio.timeout(WAIT_S):
        await gate.reached.wait()
    await until(lambda: harness.robot.moves_waiting == 1)
    return gate, reader


async def test_a_hold_refuses_a_move_queued_behind_another_command(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings))
        await step_recorded(daemon, 1)
        gate, reader = await _queue_a_move_behind_a_pose_read(harness)
        written = list(harness.robot.commands)
        await daemon.hold_robot()
        gate.open()
        await reader
        queued_step = daemon.run.step + 1 if daemon.run is not None else -1
        await step_recorded(daemon, queued_step)
        assert harness.robot.commands == written  # the queued move never went out
        view = daemon.run
        assert view is not None and view.last_record is not None
        assert "robot-error" in view.last_record["flags"]
        assert (view.state, view.reason) == (RunState.PAUSED, "robot held by request")
        await daemon.stop()


async def test_hold_through_the_server_answers_once_no_move_can_go_out(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api
    assert (await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)).is_success
    await step_recorded(harness.daemon, 1)
    gate, reader = await _queue_a_move_behind_a_pose_read(harness)
    written = list(harness.robot.commands)
    held = await client.post("/api/v1/robot/stop", headers=CONTROL_HEADERS)
    assert held.status_code == 200 and held.json() == {"held": True, "state": "paused"}
    gate.open()
    await reader
    await step_recorded(harness.daemon, harness.daemon.run.step + 1)  # type: ignore[union-attr]
    assert harness.robot.commands == written


async def test_the_hold_does_not_wait_for_a_state_write(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        recorder, release = daemon.recorder, threading.Event()
        set_run_state = recorder.set_run_state

        def slow_fsync(run_id: int, state: str, reason: str | None = None) -> None:
            release.wait(WAIT_S)  # a disk that takes its time
            set_run_state(run_id, state, reason)

        await daemon.start_run(params(settings))
        await step_recorded(daemon, 1)
        recorder.set_run_state = slow_fsync  # type: ignore[method-assign]
        try:
            async with asyncio.timeout(1.0):  # far less than the write is held up
                await daemon.hold_robot()
            assert harness.robot.held
        finally:
            release.set()
        await daemon.stop()


async def test_a_hold_while_starting_cancels_the_start(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.permit.hold("the previous run ended")  # the start resumes it
        gate = Gate()
        harness.robot.resume_gate = gate
        await daemon.start_run(params(settings))
        async with asyncio.timeout(WAIT_S):
            await gate.reached.wait()
        await daemon.hold_robot()  # lands while the start is resuming the robot
        gate.open()
        final = await daemon.wait_run()
    assert final["state"] == "stopped" and final["reason"].startswith("start cancelled")
    assert harness.robot.held and harness.robot.commands == []


async def test_a_hold_right_after_the_start_request_is_never_released(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings))
        await daemon.hold_robot()  # before the run task has done anything
        final = await daemon.wait_run()
    assert final["state"] == "stopped" and final["reason"].startswith("start cancelled")
    assert harness.robot.held and harness.robot.resumes == 0 and harness.robot.commands == []


# --- 5. never wedged -----------------------------------------------------------------------


def _raise(*_args: Any, **_kwargs: Any) -> Any:
    raise RuntimeError("injected")


async def _raise_async(*_args: Any, **_kwargs: Any) -> Any:
    raise RuntimeError("injected")


INJECTIONS: dict[str, Callable[[pytest.MonkeyPatch, Harness], None]] = {
    "prepare": lambda mp, h: mp.setattr(h.robot, "teach_goal", _raise_async),
    "model": lambda mp, h: mp.setattr(StepPipeline, "_advance_model", _raise_async),
    "move": lambda mp, h: mp.setattr(h.robot, "move_absolute", _raise_async),
    "measure": lambda mp, h: mp.setattr(measure_module, "measure_with_camera_settings", _raise),
    "record": lambda mp, h: mp.setattr(h.daemon.recorder, "write_step", _raise),
    "loop": lambda mp, h: mp.setattr(FixedStepTimer, "step_done", _raise),
}


@pytest.mark.parametrize("stage", list(INJECTIONS))
async def test_an_unexpected_error_at_any_stage_ends_the_run_and_frees_the_daemon(
    tmp_path: Path, stage: str, caplog: pytest.LogCaptureFixture
) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with pytest.MonkeyPatch.context() as patch:
            INJECTIONS[stage](patch, harness)
            await daemon.start_run(params(settings, duration_s=5.0))
            final = await daemon.wait_run()
        assert final["state"] == "aborted" and final["reason"] == "RuntimeError: injected"
        assert harness.robot.held and daemon.snapshot()["state"] == "idle"
        assert "Traceback" in caplog.text  # the journal has the traceback
        again = await daemon.start_run(params(settings, duration_s=3.0))  # no restart needed
        assert (await daemon.wait_run())["state"] == "finished"
        assert daemon.recorder is not None
        row = daemon.recorder.run(final["id"])
    assert row is not None and (row.state, row.reason) == ("aborted", "RuntimeError: injected")
    assert again["id"] == final["id"] + 1


@pytest.mark.parametrize("part", ["summary", "end record"])
async def test_an_error_while_ending_still_ends_the_run(
    tmp_path: Path, part: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(service_module, "UNRECORDED_END_RETRY_S", 0.01)
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        recorder = daemon.recorder
        finish_run, failures = recorder.finish_run, []

        def failing_once(*args: Any) -> None:
            if not failures:
                failures.append(args)
                raise RuntimeError("injected")
            finish_run(*args)

        if part == "summary":
            monkeypatch.setattr(TwoLinkKind, "summary", _raise)
        else:
            monkeypatch.setattr(recorder, "finish_run", failing_once)
        info = await daemon.start_run(params(settings, duration_s=5.0))
        final = await daemon.wait_run()
        assert final["state"] == "finished" and daemon.snapshot()["state"] == "idle"
        await until(lambda: (r := recorder.run(info["id"])) is not None and r.state == "finished")
        second = await daemon.start_run(params(settings, duration_s=3.0))
        assert (await daemon.wait_run())["state"] == "finished" and second["id"] == info["id"] + 1


# --- 6. the loop owns its workers ----------------------------------------------------------


async def test_blocked_api_reads_do_not_stall_the_control_loop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a run long enough to outlast the reads' setup on a loaded machine: the suite's default
    # minute ends in ~0.6 s of wall time at the accelerated clock, and beside two busy loops it
    # once ended before ten more steps could be counted
    settings = api_settings(
        make_settings(tmp_path, bench={"clock": "accelerated"}, scheduler={"duration_s": 86400.0})
    )
    harness = Harness(settings)
    app = create_app(settings, service_factory=lambda _settings: harness.daemon)
    reading, release = threading.Semaphore(0), threading.Event()
    threads: set[str] = set()
    run_row = Recorder.run

    def blocked_read(self: Recorder, run_id: int) -> Any:
        threads.add(threading.current_thread().name)
        reading.release()
        release.wait(WAIT_S)
        return run_row(self, run_id)

    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=WAIT_S) as client,
    ):
        created = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
        run_id = created.json()["id"]
        await step_recorded(harness.daemon, 2)
        monkeypatch.setattr(Recorder, "run", blocked_read)
        try:
            reads = [asyncio.create_task(client.get(f"/api/v1/runs/{run_id}")) for _ in range(6)]
            await until(lambda: reading._value >= 2)  # every read thread is stuck now
            before = harness.daemon.run.step  # type: ignore[union-attr]
            await step_recorded(harness.daemon, before + 10)  # the loop goes on regardless
        finally:
            release.set()
        answers = await asyncio.gather(*reads)
        assert [a.status_code for a in answers] == [200] * 6
        assert threads and all(name.startswith("api-read") for name in threads)
        # a large export meanwhile is encoded in export processes, not by this process
        page = await client.get(f"/api/v1/runs/{run_id}/steps?limit=5000")
        assert page.status_code == 200 and page.json()["steps"][0]["step"] == 0
        state = (await client.get("/api/v1/state")).json()
        assert state["errors"] == []  # no camera timeout, no refused grab


# --- 7. bounded parameters ------------------------------------------------------------------


async def test_unbounded_run_parameters_are_refused_by_the_server(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    _, client = api
    for body, field in (
        ('{"warmup_wait_s": 1e308}', "body.warmup_wait_s"),
        ('{"duration_s": 1e400}', "body.duration_s"),
        ('{"arc_period_s": 1e308}', "body.arc_period_s"),
        ('{"heat_w": {"2": 1e308}}', "body.heat_w.2"),
    ):
        answer = await client.post(
            "/api/v1/runs",
            content=body,
            headers={**CONTROL_HEADERS, "Content-Type": "application/json"},
        )
        assert answer.status_code == 422, body
        assert field in {d["field"] for d in answer.json()["details"]}, answer.json()


async def test_long_warmups_never_poison_the_clock_or_the_next_run(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        for _ in range(3):  # the longest admissible warm-up, again and again
            await daemon.start_run(params(settings, duration_s=3.0, warmup_wait_s=86400.0))
            assert (await daemon.wait_run())["state"] == "finished"
        assert math.isfinite(daemon.clock.now())


async def test_the_virtual_clock_refuses_a_deadline_at_infinity() -> None:
    clock = VirtualClock()
    with pytest.raises(ValueError, match="not finite"):
        await clock.sleep_until(math.inf)
    assert clock.now() == 0.0


# --- 8. storage failures recorded truthfully -------------------------------------------------


async def test_a_disk_full_end_is_recorded_once_writing_works_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(service_module, "UNRECORDED_END_RETRY_S", 0.01)
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    disk_full = threading.Event()
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        recorder = daemon.recorder
        write_step, finish_run = recorder.write_step, recorder.finish_run

        def full_write(record: StepRecord) -> None:
            if record.step >= 3:
                disk_full.set()
            if disk_full.is_set():
                raise RecorderError("database or disk is full")
            write_step(record)

        def full_finish(*args: Any) -> None:
            if disk_full.is_set():
                raise RecorderError("database or disk is full")
            finish_run(*args)

        monkeypatch.setattr(recorder, "write_step", full_write)
        monkeypatch.setattr(recorder, "finish_run", full_finish)
        info = await daemon.start_run(params(settings))
        final = await daemon.wait_run()
        assert final["state"] == "aborted" and "disk is full" in final["reason"]
        assert daemon.snapshot()["run"]["reason"] == final["reason"]  # the API sees it now
        with pytest.raises(RecorderError, match="not recorded yet"):
            await daemon.start_run(params(settings))  # never two live runs
        disk_full.clear()  # space freed
        await until(lambda: (r := recorder.run(info["id"])) is not None and r.state == "aborted")
        second = await daemon.start_run(params(settings, duration_s=3.0))
        await daemon.wait_run()
    with Recorder(tmp_path) as reopened:  # after a restart: the reason is kept
        row = reopened.run(info["id"])
        live = [r for r in reopened.runs() if r.state in ("running", "starting")]
    assert row is not None and row.state == "aborted" and "disk is full" in (row.reason or "")
    assert live == [] and second["id"] == info["id"] + 1


# --- 9. resume after the controller lost the taught goal ------------------------------------


async def test_resume_is_refused_when_the_controller_lost_the_goal(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.fail_moves = {3}  # the link fails: the controller restarts meanwhile
        await daemon.start_run(params(settings))
        assert await daemon.wait_state(RunState.FAULT) is RunState.FAULT
        harness.robot.resume_error = GoalLostError(
            "robot", "the controller lost the taught goal 'opgoal'"
        )
        moves = harness.robot.moves
        with pytest.raises(ResumeRefusedError, match="the controller lost the taught goal"):
            await daemon.resume()
        view = daemon.run
        assert view is not None and view.state is RunState.FAULT
        assert view.reason is not None and "lost the taught goal" in view.reason
        assert harness.robot.held and harness.robot.moves == moves
        final = await daemon.stop()
    assert final["state"] == "aborted"


async def test_resume_refused_through_the_server_is_a_409_saying_why(
    api: tuple[Harness, httpx.AsyncClient],
) -> None:
    harness, client = api
    harness.robot.fail_moves = {3}
    run_id = (await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)).json()["id"]
    await until(
        lambda: harness.daemon.run is not None and harness.daemon.run.state is RunState.FAULT
    )
    harness.robot.resume_error = GoalLostError("robot", "the controller lost the taught goal")
    answer = await client.post(f"/api/v1/runs/{run_id}/resume", headers=CONTROL_HEADERS)
    assert answer.status_code == 409 and "lost the taught goal" in answer.json()["message"]
    assert (await client.get("/api/v1/state")).json()["state"] == "fault"


# --- 10. final states say what happened ------------------------------------------------------


async def test_final_states_say_what_happened(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with caplog.at_level(logging.INFO):
            await daemon.start_run(params(settings, duration_s=5.0))
            ended = await daemon.wait_run()
        assert ended["state"] == "finished" and ended["reason"] is None
        assert [r for r in caplog.records if r.levelno >= logging.WARNING] == []
        await daemon.start_run(params(settings))
        stopped = await daemon.stop(reason="stopped by request (alice: lunch)")
    assert (stopped["state"], stopped["reason"]) == ("stopped", "stopped by request (alice: lunch)")
    assert RunState.STOPPED.is_terminal and not RunState.STOPPED.is_active


# --- 3. shutdown order of a machine that moves (the real server, a real process) --------------


@pytest.mark.slow
@pytest.mark.parametrize("signals", [(signal.SIGTERM,), (signal.SIGINT, signal.SIGINT)])
def test_a_signal_holds_and_ends_the_run_before_http_drains(
    tmp_path: Path, signals: tuple[signal.Signals, ...]
) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}/api/v1"
    env = {
        **os.environ,
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path),
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
    }
    process = subprocess.Popen(
        cli_command("serve", "--config", SIM, "--host", "127.0.0.1", "--port", str(port)),
        cwd=REPO_ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                httpx.get(f"{base}/health", timeout=1.0)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline and process.poll() is None, "no server"
                time.sleep(0.05)
        created = httpx.post(f"{base}/runs", json={}, headers=CONTROL_HEADERS, timeout=WAIT_S)
        assert created.status_code == 201
        while httpx.get(f"{base}/state", timeout=WAIT_S).json()["state"] != "running":
            assert time.monotonic() < deadline
            time.sleep(0.05)
        for sent in signals:  # a second Ctrl-C is uvicorn's forced exit
            process.send_signal(sent)
        output, _ = process.communicate(timeout=WAIT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    lines = output.splitlines()
    ended = next(i for i, line in enumerate(lines) if "run 1 stopped (daemon shut down)" in line)
    draining = next(i for i, line in enumerate(lines) if "uvicorn.error: Shutting down" in line)
    assert ended < draining, output  # the run was over before the connections drained
    closed = next(i for i, line in enumerate(lines) if "api.serve: daemon closed" in line)
    assert draining < closed, output  # devices and database closed after, forced exit too
    with Recorder(tmp_path) as recorder:
        row = recorder.run(1)
    assert row is not None and (row.state, row.reason) == ("stopped", "daemon shut down")


async def test_an_ended_run_stops_making_progress(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings, duration_s=60.0))
        await step_recorded(daemon, 5)
        stopped = await daemon.stop()
        await daemon.clock.sleep_until(daemon.clock.now() + 30.0)  # time goes on after it
        later = daemon.snapshot()["run"]
    assert later["progress_percent"] == stopped["progress_percent"] < 100.0


@pytest.mark.slow
async def test_a_run_on_the_real_driver_ends_without_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The C500C driver over the emulator's pty (the bench): a run that ends normally holds
    the robot as routine, not as a fault (issue 15, point 10), and /state's robot error stays
    empty (point 8)."""
    settings = Settings.model_validate(
        {"storage": {"data_dir": str(tmp_path), "report_at_end": False}}
    )
    async with Daemon(settings) as daemon:
        with caplog.at_level(logging.INFO):
            await daemon.start_run(params(settings, duration_s=5.0))
            final = await daemon.wait_run()
        robot = daemon.snapshot()["robot"]
    assert final["state"] == "finished"
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []
    assert robot["motion_held"] and robot["last_error"] is None
    assert robot["hold_reason"] == "run 1 finished"  # the run's own hold says why (issue 26)
