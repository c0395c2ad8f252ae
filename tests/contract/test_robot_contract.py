"""The Robot contract (drivers/base.py, issue 26): what every robot driver and every fake must
do, run over each of tests/contract/adapters.py. A driver that does not pass it is not a
driver; a fake that does not pass it goes.

The hold (drivers/permit.py): from the call of stop(), before its first await, no motion
command reaches the writer, whatever was in flight or queued; only a resume() whose ticket is
newer than the hold releases it. Targets: non-finite or beyond the drivers' bound refused
before any byte. The link: a lost goal refuses the resume; a dropped or stalled link is a fault
within seconds that holds motion until an explicit resume. Cancellation: any public coroutine
cancelled mid-exchange leaves the robot usable (a cut move holds)."""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from drivers.base import LinkState
from drivers.errors import (
    DeviceError,
    DeviceTimeoutError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
)
from tests.contract.adapters import RECONNECT_S, Subject

STEP = (0.001, 0.0, 0.0)
WAIT_S = 30.0


async def _started(subject: Subject, coroutine: object) -> asyncio.Task[object]:
    """``coroutine`` started, with its exchange in flight (its reply held back)."""
    subject.hold_replies()
    task: asyncio.Task[object] = asyncio.ensure_future(coroutine)  # type: ignore[arg-type]
    await asyncio.wait_for(subject.reply_held(), WAIT_S)
    return task


async def _hold_now(subject: Subject) -> asyncio.Task[None]:
    """stop() called and run to its first await: the hold must already be in force."""
    stop = asyncio.ensure_future(subject.robot.stop())
    await asyncio.sleep(0)
    assert subject.robot.permit.held
    return stop


async def test_stop_holds_before_its_first_await(subject: Subject) -> None:
    robot, written = subject.robot, subject.written()
    stop = await _hold_now(subject)
    with pytest.raises(MotionHeldError):
        await robot.move_absolute(STEP)
    await stop
    assert subject.written() == written and robot.status().motion_held


async def test_a_hold_during_resume_survives_it(subject: Subject) -> None:
    robot = subject.robot
    await robot.stop()
    written = subject.written()
    resume = await _started(subject, robot.resume())
    stop = await _hold_now(subject)
    subject.release_replies()
    with pytest.raises(MotionHeldError):
        await resume
    await stop
    with pytest.raises(MotionHeldError):
        await robot.move_absolute(STEP)
    assert subject.written() == written and robot.permit.held


async def test_a_hold_refuses_a_move_queued_behind_a_command_in_flight(subject: Subject) -> None:
    """A move in flight (its reply held back) and a second one queued behind it: after the
    hold the queued one is never written; the one in flight may end or be halted."""
    robot, written = subject.robot, subject.written()
    first = await _started(subject, robot.move_absolute(STEP))
    queued = asyncio.ensure_future(robot.move_absolute((0.002, 0.0, 0.0)))
    await asyncio.sleep(0)
    stop = await _hold_now(subject)
    subject.release_replies()
    await asyncio.gather(first, return_exceptions=True)
    with pytest.raises(MotionHeldError):
        await queued
    await stop
    assert subject.written() <= written + 1  # at most the one already on the wire


async def test_after_a_hold_teach_is_allowed_moves_are_not_and_only_a_newer_resume_releases(
    subject: Subject,
) -> None:
    robot = subject.robot
    before = robot.permit.ticket()  # a request that arrived before the hold
    await robot.stop()
    written = subject.written()
    await robot.teach_goal()  # moves nothing: allowed while held
    with pytest.raises(MotionHeldError):
        await robot.move_absolute(STEP)
    with pytest.raises(MotionHeldError):
        await robot.resume(before)
    assert subject.written() == written and robot.permit.held
    await robot.resume()  # a request made after the hold
    await robot.move_absolute(STEP)
    assert subject.written() == written + 1 and not robot.permit.held


@pytest.mark.parametrize(
    "offset",
    [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, -math.inf), (1001.0, 0.0, 0.0)],
)
async def test_a_non_finite_or_over_limit_target_is_refused_before_any_byte(
    subject: Subject, offset: tuple[float, float, float]
) -> None:
    robot, written = subject.robot, subject.written()
    with pytest.raises(DeviceError, match="refused"):
        await robot.move_absolute(offset)
    with pytest.raises(DeviceError, match="refused"):
        await robot.move_absolute(STEP, (math.nan, 0.0, 0.0))
    with pytest.raises(DeviceError):
        await robot.move_absolute(STEP, goal="not taught")
    assert subject.written() == written and not robot.permit.held
    await robot.move_absolute(STEP)  # the link is untouched
    assert subject.written() == written + 1


async def test_a_lost_goal_refuses_the_resume_and_the_hold_stays(subject: Subject) -> None:
    robot = subject.robot
    await robot.stop()
    written = subject.written()
    subject.lose_goals()
    async with asyncio.timeout(RECONNECT_S):
        while True:  # a restarted controller may first cost the link a reconnection
            try:
                await robot.resume()
            except GoalLostError:
                break
            except (NotConnectedError, DeviceTimeoutError):
                await asyncio.sleep(0.05)
            else:
                pytest.fail("a resume released a controller that lost the taught goal")
    with pytest.raises(MotionHeldError):
        await robot.move_absolute(STEP)
    assert subject.written() == written and robot.permit.held


async def test_a_dropped_link_holds_until_an_explicit_resume(subject: Subject) -> None:
    robot, written = subject.robot, subject.written()
    subject.drop_link()
    with pytest.raises(DeviceError):
        await robot.move_absolute(STEP)
    assert robot.permit.held
    await subject.reconnected()
    with pytest.raises(MotionHeldError):
        await robot.move_absolute(STEP)  # reconnected, still held
    assert subject.written() == written
    async with asyncio.timeout(RECONNECT_S):
        await robot.resume()
    await robot.move_absolute(STEP)
    assert subject.written() == written + 1


async def test_a_stalled_move_is_a_fault_within_seconds(subject: Subject) -> None:
    robot = subject.robot
    subject.stall_next_move()
    began = time.monotonic()
    with pytest.raises(DeviceTimeoutError):
        await robot.move_absolute(STEP)
    took_s = time.monotonic() - began
    assert took_s < subject.stall_budget_s + 5.0  # slack for a loaded machine, not 60 s
    status = robot.status()
    assert status.motion_held and status.link is LinkState.STALLED


@pytest.mark.parametrize("call", ["teach_goal", "actual_pose", "move_absolute", "resume"])
async def test_a_cancelled_call_leaves_the_robot_usable(subject: Subject, call: str) -> None:
    robot = subject.robot
    if call == "resume":
        await robot.stop()
    coroutine = robot.move_absolute(STEP) if call == "move_absolute" else getattr(robot, call)()
    task = await _started(subject, coroutine)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    subject.release_replies()
    if call == "move_absolute":
        assert robot.permit.held  # a cut move holds: it may have been written
    async with asyncio.timeout(RECONNECT_S):
        while True:  # a link dirtied by the cut comes back clean on its own
            try:
                await robot.actual_pose()
                break
            except DeviceError:
                await asyncio.sleep(0.05)
        await robot.resume()
    await robot.move_absolute(STEP)
    assert not robot.permit.held
