"""The control loop on its own thread (daemon/run/control_loop.py): calls cross to it and back,
the outbox to the API's loop is bounded and ordered, the scheduling it asks for falls back with
one line, a hold from another thread is atomic against a driver's check-then-write, and a run's
steps go on while the API's loop is blocked."""

from __future__ import annotations

import asyncio
import logging
import os
import threading
import time
from pathlib import Path

import pytest

from daemon.run import control_loop
from daemon.run.control_loop import ControlLoop, HomeOutbox, realtime_scheduling
from daemon.run.states import RunState
from drivers.errors import MotionHeldError
from drivers.permit import MotionPermit
from tests.fakes import Harness, make_settings, params


async def test_calls_run_on_the_control_thread_and_answer_here() -> None:
    async with ControlLoop(threaded=True) as control:
        home = threading.current_thread()

        async def where() -> str:
            await asyncio.sleep(0)
            return threading.current_thread().name

        assert await control.call(where) == "control-loop"
        assert await control.run(lambda: threading.current_thread().name) == "control-loop"
        assert threading.current_thread() is home

        async def fails() -> None:
            raise ValueError("from the control loop")

        with pytest.raises(ValueError, match="from the control loop"):
            await control.call(fails)


async def test_a_cancelled_caller_cancels_the_call_on_the_control_loop() -> None:
    async with ControlLoop(threaded=True) as control:
        cancelled = threading.Event()

        async def forever() -> None:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                cancelled.set()
                raise

        caller = asyncio.create_task(control.call(forever))
        await asyncio.sleep(0.05)
        caller.cancel()
        with pytest.raises(asyncio.CancelledError):
            await caller
        assert await asyncio.to_thread(cancelled.wait, 5.0)


async def test_without_a_thread_calls_simply_await_here() -> None:
    async with ControlLoop(threaded=False) as control:
        loop = asyncio.get_running_loop()

        async def which() -> asyncio.AbstractEventLoop:
            return asyncio.get_running_loop()

        assert await control.call(which) is loop
        assert control.on_control_thread()


async def test_the_outbox_keeps_order_and_drops_the_oldest_past_its_bound() -> None:
    outbox = HomeOutbox(asyncio.get_running_loop(), size=5)
    seen: list[int] = []

    def post_all() -> None:
        for i in range(12):
            outbox.post(lambda i=i: seen.append(i))  # type: ignore[misc]

    poster = threading.Thread(target=post_all)
    poster.start()
    poster.join()  # this loop is blocked meanwhile: nothing drains until it runs again
    for _ in range(5):
        await asyncio.sleep(0)
    assert seen == [7, 8, 9, 10, 11]
    assert outbox.dropped == 7


def test_scheduling_not_permitted_falls_back_and_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", refuse)
    said = realtime_scheduling(10)
    assert said.startswith("normal scheduling") and "not permitted" in said
    assert "LimitRTPRIO" in said
    assert realtime_scheduling(0).startswith("normal scheduling")


async def test_the_thread_logs_one_line_of_what_it_runs_with(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", refuse)
    with caplog.at_level(logging.INFO, logger=control_loop.__name__):
        async with ControlLoop(threaded=True, realtime_priority=10):
            pass
    lines = [r.getMessage() for r in caplog.records if r.name == control_loop.__name__]
    assert len(lines) == 1 and "not permitted" in lines[0]


def test_a_hold_from_another_thread_waits_for_a_write_in_progress() -> None:
    """The driver's check-then-write (MotionPermit.guard) is atomic against a hold from
    another thread: the hold lands before the check (refused) or after the write."""
    permit = MotionPermit()
    holder = threading.Thread(target=permit.hold, args=("from the API's thread",))
    with permit.guard():
        holder.start()
        holder.join(0.1)
        assert holder.is_alive()  # the hold waits: the bytes are being handed to the port
        assert not permit.held
    holder.join(5.0)
    assert permit.held
    with pytest.raises(MotionHeldError), permit.guard():
        pass  # a check after the hold refuses the write


async def test_steps_go_on_while_the_api_loop_is_blocked(tmp_path: Path) -> None:
    """The old single loop recorded no step while the API's loop was busy; the control loop's
    thread keeps stepping (a blocked API loop stands for a slow request handler)."""
    settings = make_settings(tmp_path, bench={"clock": "real"})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings, step_s=0.02, duration_s=600.0))
        await daemon.wait_state(RunState.RUNNING)
        while (view := daemon.run) is None or view.step < 2:  # noqa: ASYNC110 -- no event here
            await asyncio.sleep(0.01)
        before = view.step
        time.sleep(1.0)  # noqa: ASYNC251 -- blocks the API's loop on purpose
        after = daemon.run
        assert after is not None
        # 50 deadlines passed; a loaded machine may skip some, not all of them
        assert after.step - before >= 10
        info = await daemon.stop()
    assert info["state"] == "stopped"
    assert harness.robot.held
