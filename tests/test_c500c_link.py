"""The real C500C driver talking to the emulator over a real pseudo-terminal (and TCP),
including every injected fault: the driver reports it, reconnects, and sends no motion until
it is resumed; a hold that holds, cut commands, the point-of-control wait, and a controller
that restarted."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Callable

import pytest

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c.console import Transcript
from drivers.c500c.robot import C500CRobot
from drivers.errors import (
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)
from drivers.sim.emulator import C500CEmulator, EmulatorConfig, FaultKind, parse_faults

# Generous against a loaded CI machine: a fault must outlast the timeout by a wide margin, and
# ordinary replies from the in-process emulator must never come near it.
COMMAND_TIMEOUT_S = 1.0
FAULT_S = 2.5 * COMMAND_TIMEOUT_S
FAST = RobotSettings(
    command_timeout_s=COMMAND_TIMEOUT_S, move_timeout_s=2.0, reconnect_max_backoff_s=0.2
)


@pytest.fixture
async def emulator() -> AsyncIterator[C500CEmulator]:
    async with C500CEmulator(EmulatorConfig(paced=False, noise_um=0.9, move_ms=1.0)) as emu:
        yield emu


async def until(condition: Callable[[], bool], timeout_s: float = 10.0) -> None:
    """Wait for a condition of the event loop's own state that has no event to await (a task
    queued on a lock): each turn of the loop lets the other tasks run."""
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 (nothing to await: asyncio.Lock has no hook)
            await asyncio.sleep(0)


def lock_waiters(robot: C500CRobot) -> int:
    """Tasks queued on the driver's lock (what a hold must stop)."""
    waiters = getattr(robot._lock, "_waiters", None)
    return 0 if waiters is None else len(waiters)


async def test_absolute_moves_are_goal_plus_offset(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        errors = []
        for step in range(20):
            offset = (0.001 * step, -0.0005 * step, 0.0)
            result = await robot.move_absolute(offset)
            # The read-back is the controller's actual pose at 0.001 mm resolution.
            assert result.actual.position == pytest.approx(
                (r := emulator.state.actual)[:3], abs=0.0005 + 1e-9
            ), r
            errors.append(result.actual.x - (goal.x + result.commanded_mm[0]))
        # Absolute commands do not accumulate error: each step is within a few sigma (0.9 um)
        # plus the console's 0.5 um rounding of the read-back.
        assert max(abs(e) for e in errors) < 0.005
    # connect: a probe line to synchronise on, the per-step target created, online
    assert list(emulator.state.commands)[:3] == ["tcsync1", "new cur", "online on"]
    assert "set cur = opgoal" in emulator.state.commands


async def test_incremental_moves_start_from_the_actual_pose(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        start = await robot.actual_pose()
        result = await robot.move_incremental((0.010, 0.0, -0.002))
    assert "wx 0.010" in emulator.state.commands and "wz -0.002" in emulator.state.commands
    assert result.actual.x == pytest.approx(start.x + 0.010, abs=0.005)


async def test_error_043_when_the_controller_is_not_online(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        emulator.state.online = False  # someone switched it off at the teach pendant
        with pytest.raises(DeviceReportedError) as caught:
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert caught.value.code == 43
        assert robot.status().motion_held and robot.status().online is False


async def test_point_of_control_waits_for_the_operator(emulator: C500CEmulator) -> None:
    """docs/reference/c500c-console.md: the PAUSE/CONTINUE request blocks the console until the
    button is pressed; the driver says so in its status and carries on after the press."""
    emulator.state.point_of_control = False
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        move = asyncio.create_task(robot.move_absolute((0.001, 0.0, 0.0)))
        await robot.wait_link(LinkState.AWAITING_POINT_OF_CONTROL, 10.0)
        assert robot.status().point_of_control is False and not move.done()
        assert emulator.state.awaiting_button
        emulator.press_pause_continue()
        result = await move
        status = robot.status()
        assert status.link is LinkState.CONNECTED and status.point_of_control
        # type: ignore[union-attr]
        assert result.actual.x == pytest.approx(robot.goal.x + 0.001, abs=0.005)


async def test_point_of_control_wait_is_bounded(emulator: C500CEmulator) -> None:
    emulator.state.point_of_control = False
    settings = FAST.model_copy(update={"point_of_control_timeout_s": 0.2})
    async with C500CRobot(settings, port=emulator.device_path) as robot:
        await robot.teach_goal()
        with pytest.raises(PointOfControlError, match="PAUSE/CONTINUE"):
            await robot.move_absolute((0.001, 0.0, 0.0))
        status = robot.status()
        assert status.motion_held and status.link is LinkState.AWAITING_POINT_OF_CONTROL
        moves_before = len(emulator.state.motion_commands())
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert len(emulator.state.motion_commands()) == moves_before
        # the operator comes: the waiting move carries on (no halt on the console,
        # docs/reference/c500c-console.md), the link is resynchronised, and motion needs an explicit
        # resume
        emulator.press_pause_continue()
        await robot.wait_link(LinkState.CONNECTED, 10.0)
        await robot.resume()
        result = await robot.move_absolute((0.002, 0.0, 0.0))
        assert result.commanded_mm == (0.002, 0.0, 0.0)


async def test_a_hold_refuses_a_move_queued_behind_a_slow_read_back(
    emulator: C500CEmulator,
) -> None:
    """Issue 15, point 2: a move waiting for the lock behind `actual_pose()` is never written
    once stop() was called."""
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        emulator.hold_answers("w2")
        reading = asyncio.create_task(robot.actual_pose())
        await emulator.answer_held.wait()  # the read-back is on the console, the lock taken
        move = asyncio.create_task(robot.move_absolute((0.002, 0.0, 0.0)))
        await until(lambda: lock_waiters(robot) == 1)  # the move queues behind it
        held = robot.stop()  # the hold is on from the call, before it is awaited
        assert robot.status().motion_held
        await held
        emulator.release_answers()
        pose = await reading
        with pytest.raises(MotionHeldError):
            await move
        status = robot.status()
        assert status.hold_reason == "stopped by request" and status.last_error is None
        assert pose.position == pytest.approx(robot.goal.position)  # type: ignore[union-attr]
        await robot.actual_pose()  # the link is fine, only motion is held
    assert emulator.state.motion_commands() == []
    assert "set cur = opgoal" not in emulator.state.commands  # nothing of the move went out


async def test_nothing_but_resume_releases_a_hold(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.stop()
        await robot.teach_goal()  # teaching moves nothing: allowed, and it keeps the hold
        await robot.actual_pose()
        with pytest.raises(MotionHeldError):
            await robot.move_incremental((0.001, 0.0, 0.0))
        assert emulator.state.motion_commands() == []
        await robot.resume()
        await robot.move_absolute((0.001, 0.0, 0.0))
    assert emulator.state.motion_commands() == ["moves cur"]


async def test_a_cancelled_command_resynchronises_before_the_next(
    emulator: C500CEmulator,
) -> None:
    """Issue 15, point 4: a `w2` cancelled mid-exchange; its answer arrives late; the next
    `w2` still reads its own answer, the status said so meanwhile."""
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        emulator.hold_answers("w2")
        reading = asyncio.create_task(robot.actual_pose())
        await emulator.answer_held.wait()
        reading.cancel()
        with pytest.raises(asyncio.CancelledError):
            await reading
        status = robot.status()
        assert status.link is LinkState.RESYNCHRONISING and not status.motion_held
        emulator.release_answers()  # the cut command's table now arrives, unread
        assert await robot.actual_pose() == goal
        status = robot.status()
        assert status.link is LinkState.CONNECTED and status.extra["resyncs"] == "1"
        result = await robot.move_absolute((0.003, 0.0, 0.0))  # motion was never held
        assert result.actual.x == pytest.approx(goal.x + 0.003, abs=0.005)


async def test_a_cut_move_holds_motion_and_the_link_recovers(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        emulator.hold_answers("finish")
        move = asyncio.create_task(robot.move_absolute((0.004, 0.0, 0.0)))
        await emulator.answer_held.wait()
        move.cancel()
        with pytest.raises(asyncio.CancelledError):
            await move
        assert robot.status().motion_held and "finish" in str(robot.status().hold_reason)
        emulator.release_answers()
        pose = await robot.actual_pose()  # the next command works on a resynchronised link
        assert pose.x == pytest.approx(goal.x + 0.004, abs=0.005)
        assert robot.status().link is LinkState.CONNECTED
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.005, 0.0, 0.0))
        await robot.resume()
        await robot.move_absolute((0.005, 0.0, 0.0))
    assert emulator.state.motion_commands() == ["moves cur", "moves cur"]


@pytest.mark.parametrize("how", ["restart now", "restart fault"])
async def test_resume_after_a_controller_restart_refuses_a_lost_goal(
    emulator: C500CEmulator, how: str
) -> None:
    """Issue 15, point 9: the controller forgot `opgoal`; resume() says so instead of
    succeeding, and no motion goes out until a goal is taught again."""
    async with C500CRobot(FAST, port=emulator.device_path, first_backoff_s=0.05) as robot:
        await robot.teach_goal()
        await robot.move_absolute((0.002, 0.0, 0.0))
        if how == "restart now":
            emulator.restart_controller()
        else:
            emulator.inject("restart")
        with pytest.raises(NotConnectedError, match="system shell"):
            await robot.actual_pose()  # answered at the `$ ` prompt
        await robot.wait_connected(5.0)  # ash started again from the shell
        assert emulator.state.restarts == 1 and not emulator.state.in_shell
        moves_before = len(emulator.state.motion_commands())
        with pytest.raises(GoalLostError) as caught:
            await robot.resume()
        assert caught.value.kind == "goal-lost"
        assert caught.value.message.startswith("the controller lost the taught goal")
        status = robot.status()
        assert status.motion_held and status.last_error == str(caught.value)
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.002, 0.0, 0.0))
        assert len(emulator.state.motion_commands()) == moves_before
        # teaching the goal again (it moves nothing) is the way back
        goal = await robot.teach_goal()
        await robot.resume()
        result = await robot.move_absolute((0.002, 0.0, 0.0))
        assert result.actual.x == pytest.approx(goal.x + 0.002, abs=0.005)


@pytest.mark.parametrize(
    ("kind", "seconds", "expected"),
    [
        ("drop", None, DeviceTimeoutError),
        ("corrupt", None, ProtocolError),
        ("delay", FAULT_S, DeviceTimeoutError),
        ("stall", FAULT_S, DeviceTimeoutError),
        ("close", None, NotConnectedError),
    ],
)
async def test_each_fault_is_reported_recovered_and_holds_motion(
    emulator: C500CEmulator, kind: FaultKind, seconds: float | None, expected: type[DeviceError]
) -> None:
    async with C500CRobot(FAST, port=emulator.device_path, first_backoff_s=0.05) as robot:
        await robot.teach_goal()
        await robot.move_absolute((0.002, 0.0, 0.0))
        emulator.inject(kind, seconds)
        with pytest.raises(expected):
            await robot.actual_pose()  # the fault strikes this `w2`
        status = robot.status()
        assert status.motion_held and status.last_error
        assert status.link in (LinkState.RECONNECTING, LinkState.CONNECTED)

        await robot.wait_connected(5.0)
        moves_before = len(emulator.state.motion_commands())
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.004, 0.0, 0.0))
        assert len(emulator.state.motion_commands()) == moves_before  # nothing sent

        await robot.resume()
        result = await robot.move_absolute((0.004, 0.0, 0.0))
        # type: ignore[union-attr]
        assert result.actual.x == pytest.approx(robot.goal.x + 0.004, abs=0.005)
        assert not robot.status().motion_held
        assert int(robot.status().extra["reconnect_attempts"]) >= 1
    assert [k for _, k in emulator.faults_applied] == [kind]
    assert robot.link_history == [
        LinkState.DISCONNECTED,
        LinkState.CONNECTING,
        LinkState.CONNECTED,
        LinkState.RECONNECTING,  # failed attempts (a stall) stay here
        LinkState.CONNECTED,
        LinkState.DISCONNECTED,
    ]


async def test_fault_during_a_move_holds_motion(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path, first_backoff_s=0.05) as robot:
        await robot.teach_goal()
        emulator.inject("drop")  # strikes `set cur = opgoal`
        with pytest.raises(DeviceTimeoutError):
            await robot.move_absolute((0.003, 0.0, 0.0))
        await robot.wait_connected(5.0)
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.003, 0.0, 0.0))
    assert emulator.state.motion_commands() == []


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
async def test_non_finite_targets_never_reach_the_console(
    emulator: C500CEmulator, bad: float
) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        sent_before = list(emulator.state.commands)
        with pytest.raises(DeviceError, match="non-finite"):
            await robot.move_absolute((0.0, bad, 0.0))
        with pytest.raises(DeviceError, match="non-finite"):
            await robot.move_incremental((bad, 0.0, 0.0))
        assert list(emulator.state.commands) == sent_before  # not a byte of it was written
        await robot.move_absolute((0.001, 0.0, 0.0))  # the link is still fine
    assert emulator.state.motion_commands() == ["moves cur"]


async def test_resume_needs_a_link(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path, first_backoff_s=1.0) as robot:
        emulator.inject("stall", 5.0)
        with pytest.raises(DeviceTimeoutError):
            await robot.actual_pose()
        with pytest.raises(NotConnectedError):
            await robot.resume()
        with pytest.raises(NotConnectedError):
            await robot.actual_pose()


async def test_opening_a_missing_port_is_not_connected() -> None:
    with pytest.raises(NotConnectedError):
        async with C500CRobot(FAST, port="/nonexistent/tty"):
            pass


async def test_tcp_transport() -> None:
    config = EmulatorConfig(paced=False, noise_um=0.0, move_ms=0.0)
    async with C500CEmulator(config, transport="tcp") as emulator:
        assert emulator.device_path.startswith("socket://127.0.0.1:")
        async with C500CRobot(FAST, port=emulator.device_path) as robot:
            goal = await robot.teach_goal()
            result = await robot.move_absolute((0.1, 0.2, -0.3))
    assert result.actual.position == pytest.approx((goal.x + 0.1, goal.y + 0.2, goal.z - 0.3))


async def test_paced_link_still_converses() -> None:
    baud = 115200
    paced = C500CEmulator(EmulatorConfig(paced=True, baudrate=baud))
    async with paced, C500CRobot(FAST, port=paced.device_path) as robot:
        await robot.teach_goal()
        lines_before = paced.state.received
        result = await robot.move_absolute((0.001, 0.0, 0.0))
        lines_of_the_move = paced.state.received - lines_before
    assert result.bytes_received > result.bytes_sent > 0
    # one round trip per write of the move (`set` and `wshift` share one), and together they
    # took at least the time the answers' bytes need on the wire: 10 bit times each (8N1)
    assert len(result.round_trips_s) == lines_of_the_move - 1 > 0
    assert all(math.isfinite(t) and t > 0 for t in result.round_trips_s)
    assert sum(result.round_trips_s) >= result.bytes_received * 10 / baud


async def test_connect_synchronises_after_stale_and_late_answers() -> None:
    """Issue 17: connect never relies on the line going quiet. Each connection's probe line
    finds the late `w2` table of the previous connection (cut while it was on its way) arriving
    first, and 30 % of the console's answers come late: every connect synchronises on its probe
    line all the same."""
    config = EmulatorConfig(paced=False, move_ms=0.0, seed=2, faults=parse_faults("delay=0.05%0.3"))
    connects = 30
    stale_first = 0
    async with C500CEmulator(config) as emulator:
        for attempt in range(connects):
            transcript = Transcript()
            robot = C500CRobot(FAST, port=emulator.device_path, transcript=transcript)
            entering = asyncio.create_task(robot.__aenter__())
            if attempt > 0:  # the previous table goes out once this probe line was written
                await until(lambda t=transcript: bool(t.sent()))  # type: ignore[misc]
                emulator.release_answers()
            await entering
            try:
                await robot.teach_goal()
                emulator.hold_answers("w2")
                reading = asyncio.create_task(robot.actual_pose())
                await emulator.answer_held.wait()
            finally:
                await robot.__aexit__(None, None, None)
            with pytest.raises(DeviceError):
                await reading  # its connection closed under it
            received = transcript.received()
            stale_first += 0 <= received.find(b"Actual Position") < received.find(b"tcsync")
        emulator.release_answers()
        async with C500CRobot(FAST, port=emulator.device_path) as robot:
            goal = await robot.teach_goal()
            result = await robot.move_absolute((0.002, 0.0, 0.0))
        assert any(kind == "delay" for _, kind in emulator.faults_applied)
    assert stale_first == connects - 1
    assert result.actual.x == pytest.approx(goal.x + 0.002, abs=0.005)


async def test_connect_retries_a_probe_answered_too_late() -> None:
    config = EmulatorConfig(paced=False, faults=parse_faults("delay=0.7@1"))
    async with C500CEmulator(config) as emulator:
        settings = FAST.model_copy(update={"command_timeout_s": 0.5})
        async with C500CRobot(settings, port=emulator.device_path) as robot:
            assert robot.status().link is LinkState.CONNECTED
            await robot.actual_pose()
    # the first probe's answer came after its wait: a second probe, whose answer is awaited
    assert list(emulator.state.commands)[:3] == ["tcsync1", "tcsync2", "new cur"]


async def test_rts_cts_flow_control_is_a_setting(emulator: C500CEmulator) -> None:
    settings = FAST.model_copy(update={"flow_control": "rtscts"})
    async with C500CRobot(settings, port=emulator.device_path) as robot:
        await robot.teach_goal()
        assert (await robot.move_absolute((0.001, 0.0, 0.0))).read_back
    with pytest.raises(ValueError, match="flow_control"):
        RobotSettings.model_validate({"flow_control": "xonxoff"})


async def test_a_hold_during_resume_is_not_released_by_it(emulator: C500CEmulator) -> None:
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        await robot.stop()
        emulator.hold_answers("w2")
        resuming = asyncio.create_task(robot.resume())
        await emulator.answer_held.wait()  # resume() is checking the console
        await robot.stop()  # a new hold while it does
        emulator.release_answers()
        with pytest.raises(MotionHeldError, match="held after the request was made"):
            await resuming
        assert robot.status().motion_held
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        await robot.resume()  # an explicit resume after the hold releases it
        await robot.move_absolute((0.001, 0.0, 0.0))
    assert emulator.state.motion_commands() == ["moves cur"]
