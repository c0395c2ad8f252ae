"""The real C500C driver talking to the emulator over a real pseudo-terminal (and TCP),
including every injected fault: the driver reports it, reconnects, and sends no motion until
it is resumed."""

from __future__ import annotations

import math
from collections.abc import AsyncIterator

import pytest

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import C500CRobot
from drivers.errors import (
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    MotionHeldError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)
from drivers.sim.emulator import C500CEmulator, EmulatorConfig, FaultKind

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
    assert list(emulator.state.commands)[:2] == ["", "online on"]
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


async def test_point_of_control_is_a_status_not_a_hang(emulator: C500CEmulator) -> None:
    emulator.state.point_of_control = False
    async with C500CRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        with pytest.raises(PointOfControlError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert robot.status().link is LinkState.AWAITING_POINT_OF_CONTROL
        moves_before = len(emulator.state.motion_commands())
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert len(emulator.state.motion_commands()) == moves_before
        emulator.press_pause_continue()
        await robot.resume()
        result = await robot.move_absolute((0.001, 0.0, 0.0))
        assert robot.status().link is LinkState.CONNECTED and robot.status().point_of_control
        assert result.commanded_mm == (0.001, 0.0, 0.0)


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
        assert result.actual.x == pytest.approx(robot.goal.x + 0.004, abs=0.005)  # type: ignore[union-attr]
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
    # one round trip per console command of the move, and together they took at least the
    # time the answers' bytes need on the wire: 10 bit times each (8N1)
    assert len(result.round_trips_s) == lines_of_the_move > 0
    assert all(math.isfinite(t) and t > 0 for t in result.round_trips_s)
    assert sum(result.round_trips_s) >= result.bytes_received * 10 / baud
