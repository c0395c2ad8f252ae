"""A pause's own refusal of the move in flight must not refuse, or undo, a resume asked after it.

A step whose move meets a pause's hold is refused (MotionHeldError) and recorded with its
fault; its verdict reaches the session after the step's record is written. Seen under load
(`make test` with two busy loops, tests/test_api_runs.py::test_full_run_cycle): the pause
answered, the resume came, and only then was that stale verdict judged: the run held the robot
again, and the resume, asked after the pause, was refused with 409 ("held after the resume was
asked"); had the resume won the race, the stale fault would have parked the resumed run in
fault. A verdict is acted on only while the run still runs under the grant its step moved for
(daemon/run/session.py ``_judge``). Synchronisation by gates and events, never by sleeping.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from daemon.run.states import RunState
from daemon.service import Daemon
from daemon.storage.recorder import StepRecord
from tests.fakes import Gate, Harness, make_settings, params, stop_with_a_move_in_flight

WAIT_S = 60.0  # bound of every wait: a hang fails, never blocks the suite


async def until(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 -- the conditions are plain attributes
            await asyncio.sleep(0.001)


async def paused_with_a_move_in_flight(harness: Harness, daemon: Daemon) -> Gate:
    """A running run paused while one step's move waits to reach the robot."""
    await daemon.start_run(params(daemon.settings, duration_s=60.0))
    await until(lambda: daemon.run is not None and daemon.run.step >= 1)
    gate = Gate()
    harness.robot.move_gate = gate
    async with asyncio.timeout(WAIT_S):
        await gate.reached.wait()
    await daemon.pause()
    assert daemon.run is not None and daemon.run.state is RunState.PAUSED
    return gate


def refused_step(daemon: Daemon) -> int | None:
    record = None if daemon.run is None else daemon.run.last_record
    return record["step"] if record and "robot-error" in record["flags"] else None


async def test_the_resume_asked_after_the_pause_is_not_refused_by_the_pause_itself(
    tmp_path: Path,
) -> None:
    harness = Harness(make_settings(tmp_path))
    async with harness.daemon as daemon:
        gate = await paused_with_a_move_in_flight(harness, daemon)
        ticket = daemon.permit.ticket()  # the resume request arrives (api/routers/runs.py)
        gate.open()  # the step's move meets the pause's hold: refused, then recorded
        await until(lambda: refused_step(daemon) is not None)
        refused = refused_step(daemon)
        assert refused is not None
        await daemon.resume(ticket)  # before: RunStateError, held after the resume was asked
        await until(lambda: daemon.run is not None and daemon.run.step >= refused + 2)
        assert daemon.run is not None and daemon.run.state is RunState.RUNNING
        assert not harness.robot.held
        final = await daemon.stop()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(final["id"])
    assert final["state"] == "stopped"
    assert [s.step for s in steps] == list(range(len(steps)))  # nothing lost
    assert "motion is held" in steps[refused].error  # the refusal stays on its record
    # and the run moved again: the steps after it until the stop moved without a flag
    assert all(s.flags == "" for s in steps[refused + 1 : refused + 3]), steps[refused:]


async def test_a_stale_verdict_does_not_fault_the_run_resumed_before_it_was_judged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    harness = Harness(make_settings(tmp_path))
    async with harness.daemon as daemon:
        recorder = daemon.recorder
        assert recorder is not None
        write_step = recorder.write_step
        writing, release = threading.Event(), threading.Event()
        refused_steps: list[int] = []

        def slow_refused_write(record: StepRecord) -> None:  # on the recorder's thread
            if "robot-error" in record.flags:
                refused_steps.append(record.step)
                writing.set()
                release.wait(WAIT_S)
            write_step(record)

        monkeypatch.setattr(recorder, "write_step", slow_refused_write)
        gate = await paused_with_a_move_in_flight(harness, daemon)
        gate.open()  # refused by the pause's hold; its record is being written
        await until(writing.is_set)
        await daemon.resume()  # asked and done before the refused step's verdict is judged
        assert daemon.run is not None and daemon.run.state is RunState.RUNNING
        [refused] = refused_steps
        release.set()
        # before: the refused step's fault verdict held the robot and parked the run in fault
        await until(lambda: daemon.run is not None and daemon.run.step >= refused + 2)
        assert daemon.run.state is RunState.RUNNING and not harness.robot.held
        # the stop comes while a move is in flight (as it once did by chance in a quiet
        # suite): the stop holds first, so that move is refused too, on the run's last step
        final = await stop_with_a_move_in_flight(daemon, harness.robot, WAIT_S)
        steps = recorder.steps(final["id"])
    assert final["state"] == "stopped"
    assert [s.step for s in steps] == list(range(len(steps)))
    # the refusal is on its record, and the run moved again, flag-free, until the stop's
    flagged = [(s.step, s.flags) for s in steps if s.flags]
    assert flagged == [(refused, "robot-error"), (steps[-1].step, "robot-error")], flagged
