"""The UR driver (drivers/ur/robot.py) against the UR emulator over loopback RTDE: state,
corrections reaching the emulated program, and drivers.base.Robot's hold contract as an
OffsetRobot keeps it (hold before anything, nothing after a hold, refusal before a byte, a
resume racing a hold, link loss, cancellation)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from config.settings import RobotSettings
from drivers.base import LinkState, OffsetRobot
from drivers.errors import DeviceError, MotionHeldError, NotConnectedError
from drivers.sim.ur.controller import URControllerConfig
from drivers.sim.ur.emulator import UREmulator
from drivers.ur import registers
from drivers.ur.modes import RobotMode, RuntimeState
from drivers.ur.robot import URRobot
from tests.loopback import loopback_host

WAIT_S = 10.0
#: The driver's link timeout in these tests (robot.ur_timeout_s): long enough that a loop
#: starved for a while on a loaded machine (the CI's 2 cores under pytest -n auto) neither
#: fails the first connection nor drops a live link; the silence test sets its own.
LINK_TIMEOUT_S = 5.0
SILENCE_TIMEOUT_S = 1.0
HOLD_PACKAGE_BYTES = 12


def settings(host: str, **changes: object) -> RobotSettings:
    values: dict[str, object] = {
        "driver": "ur-rtde",
        "host": host,
        "rtde_frequency_hz": 125.0,
        "ur_timeout_s": LINK_TIMEOUT_S,
        "reconnect_max_backoff_s": 0.2,
    }
    values.update(changes)
    return RobotSettings.model_validate(values)


@asynccontextmanager
async def bench(
    host: str, *, autoplay: bool = True, link_timeout_s: float = LINK_TIMEOUT_S
) -> AsyncIterator[tuple[UREmulator, URRobot]]:
    async with (
        UREmulator(URControllerConfig(autoplay=autoplay), host=host) as ur,
        URRobot(settings(host, ur_timeout_s=link_timeout_s), first_backoff_s=0.05) as robot,
    ):
        await until(lambda: robot._state is not None)
        yield ur, robot


async def until(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 -- the state changes on the loop's tasks
            await asyncio.sleep(0.005)


def fresh(robot: URRobot) -> bool:
    try:
        robot.robot_state()
    except NotConnectedError:
        return False
    return True


def bytes_sent(robot: URRobot) -> int:
    client = robot._client
    assert client is not None
    return client.bytes_sent


async def test_state_and_a_correction_applied_by_the_emulated_program() -> None:
    async with bench(loopback_host(), autoplay=False) as (ur, robot):
        offset_robot: OffsetRobot = robot  # the protocol, checked by mypy
        assert offset_robot.status().link is LinkState.CONNECTED
        state = robot.robot_state()
        assert state.robot_mode == RobotMode.RUNNING
        assert state.runtime_state == RuntimeState.STOPPED
        assert len(state.joints_rad) == 6 and len(state.joint_temperatures_c) == 6
        nominal = state.tcp_pose
        assert nominal[:3] == pytest.approx([v * 1000 for v in ur.controller.tcp_pose(0.0)[:3]])
        assert ur.dashboard.commands == []
        await robot.dashboard.play()
        assert await robot.dashboard.program_state() == "PLAYING"
        await robot.dashboard.pause()
        assert await robot.dashboard.program_state() == "PAUSED"
        sequence = await robot.set_correction((0.1, 0.0, -0.05), (0.0, 0.0, 1e-4))
        await asyncio.sleep(0.1)
        # paused: the program (and its thread) does not run, nothing is accepted or applied
        assert robot.robot_state().accepted_sequence < sequence
        assert robot.robot_state().applied_offset_mm == (0.0, 0.0, 0.0)
        await robot.dashboard.play()
        await until(lambda: robot.robot_state().accepted_sequence >= sequence)
        await until(lambda: robot.robot_state().applied_offset_mm[0] == pytest.approx(0.1))


LONG_DWELL = """
name = "long-dwell"
arm = "ur5e"
max_speed_deg_s = 180.0
max_accel_deg_s2 = 360.0
[[poses]]
name = "camera"
joints_deg = [0.0, -100.0, 100.0, -90.0, -90.0, 0.0]
dwell_s = 60.0
measure = true
[[poses]]
name = "away"
joints_deg = [30.0, -100.0, 100.0, -90.0, -90.0, 0.0]
"""


async def test_the_offset_reaches_the_program_and_moves_the_tool(tmp_path: Path) -> None:
    duty = tmp_path / "long-dwell.toml"
    duty.write_text(LONG_DWELL)  # the robot dwells at a measured pose while the offset moves
    host = loopback_host()
    async with (
        UREmulator(URControllerConfig(duty=str(duty)), host=host),
        URRobot(settings(host), first_backoff_s=0.05) as robot,
    ):
        await until(lambda: robot._state is not None)
        before = robot.robot_state().tcp_pose
        sequence = await robot.set_correction((0.1, 0.0, -0.05), (0.0, 0.0, 1e-4))
        await until(
            lambda: (
                robot.robot_state().accepted_sequence >= sequence
                and robot.robot_state().applied_offset_mm == pytest.approx((0.1, 0.0, -0.05))
            )
        )
        state = robot.robot_state()
        assert state.at_pose == 1  # dwelling at the camera pose, a measured one
        assert state.applied_rotation_rad == pytest.approx((0.0, 0.0, 1e-4))
        moved = [a - b for a, b in zip(state.tcp_pose[:3], before[:3], strict=True)]
        # the emulated arm's joints carry the offset: the tool moved by it (mm)
        assert moved == pytest.approx([0.1, 0.0, -0.05], abs=2e-4)


async def test_hold_is_effective_before_its_first_await_and_freezes_the_program() -> None:
    async with bench(loopback_host()) as (ur, robot):
        await robot.set_correction((0.2, 0.0, 0.0))
        sent = bytes_sent(robot)
        await until(lambda: ur.controller.writes[robot.registers.target[0]] == 1)
        target_writes = 1  # the correction above reached the controller
        pending = robot.stop()  # not awaited yet
        # the hold recipe's package (sequence, hold flag: 3 + 1 + 4 + 4 bytes), at once
        assert bytes_sent(robot) == sent + HOLD_PACKAGE_BYTES
        assert robot.status().motion_held and robot.permit.held
        with pytest.raises(MotionHeldError):
            await robot.set_correction((0.0, 0.0, 0.0))
        assert bytes_sent(robot) == sent + HOLD_PACKAGE_BYTES  # nothing of the refused one
        await pending
        await until(lambda: robot.robot_state().program_status & registers.STATUS_HELD != 0)
        frozen = robot.robot_state().applied_offset_mm
        await asyncio.sleep(0.2)
        assert robot.robot_state().applied_offset_mm == frozen  # frozen, not back to zero
        assert ur.controller.inputs[robot.registers.hold] == 1
        # heartbeats went on, never into the correction registers
        assert ur.controller.writes[robot.registers.target[0]] == target_writes
        await robot.resume()
        assert not robot.status().motion_held
        await robot.set_correction((0.2, 0.0, 0.0))
        await until(lambda: robot.robot_state().applied_offset_mm[0] == pytest.approx(0.2))


async def test_a_resume_racing_a_hold_never_releases_it() -> None:
    async with bench(loopback_host()) as (_, robot):
        await robot.stop()
        async with robot._lock:  # the resume waits here, as behind a reconnection
            resume = asyncio.create_task(robot.resume())
            await asyncio.sleep(0.01)
            await robot.stop()  # a later hold, while the resume waits
        with pytest.raises(MotionHeldError, match="stays held"):
            await resume
        assert robot.status().motion_held
        with pytest.raises(MotionHeldError):
            await robot.set_correction((0.0, 0.0, 0.0))
        await robot.resume()  # a request made after the hold releases it
        await robot.set_correction((0.0, 0.0, 0.0))


@pytest.mark.parametrize(
    ("offset", "rotation"),
    [
        ((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0)),
        ((0.0, math.inf, 0.0), (0.0, 0.0, 0.0)),
        ((0.0, 0.0, 0.0), (0.0, -math.inf, 0.0)),
        ((0.8, 0.8, 0.0), (0.0, 0.0, 0.0)),  # 1.13 mm > robot.correction_limit_mm 1.0
        ((0.0, 0.0, 0.0), (0.0, 0.0008, 0.0008)),  # 1.13 mrad > 1.0
    ],
)
async def test_bad_corrections_are_refused_before_any_byte(
    offset: tuple[float, float, float], rotation: tuple[float, float, float]
) -> None:
    async with bench(loopback_host()) as (ur, robot):
        sent = bytes_sent(robot)
        with pytest.raises(DeviceError, match="refused"):
            await robot.set_correction(offset, rotation)
        assert bytes_sent(robot) == sent
        assert ur.controller.inputs[robot.registers.target[0]] == 0.0


async def test_link_loss_holds_reconnects_and_stays_held_until_resume() -> None:
    async with bench(loopback_host()) as (ur, robot):
        await robot.set_correction((0.05, 0.0, 0.0))
        ur.drop_connections()
        await until(lambda: robot.status().motion_held)
        assert "link lost" in (robot.status().hold_reason or "")
        with pytest.raises((MotionHeldError, NotConnectedError)):
            await robot.set_correction((0.0, 0.0, 0.0))
        await until(
            lambda: (
                robot.status().link is LinkState.CONNECTED
                and robot.status().extra["reconnect_attempts"] == "1"
            )
        )
        assert robot.status().motion_held  # never released on its own
        await until(lambda: ur.controller.inputs[robot.registers.hold] == 1)
        with pytest.raises(MotionHeldError):
            await robot.set_correction((0.0, 0.0, 0.0))
        await until(lambda: fresh(robot))
        await robot.resume()
        await robot.set_correction((0.0, 0.0, 0.0))


async def test_silence_is_a_fault_within_the_timeout() -> None:
    async with bench(loopback_host(), link_timeout_s=SILENCE_TIMEOUT_S) as (ur, robot):
        ur.silence(True)
        await until(lambda: robot.status().motion_held)
        assert "link lost" in (robot.status().hold_reason or "")
        with pytest.raises(NotConnectedError):
            robot.robot_state()
        ur.silence(False)
        await until(lambda: robot.status().link is LinkState.CONNECTED)
        assert robot.status().motion_held


async def test_closing_the_driver_sets_the_hold_flag_first() -> None:
    host = loopback_host()
    async with UREmulator(host=host) as ur:
        async with URRobot(settings(host)) as robot:
            await robot.set_correction((0.1, 0.0, 0.0))
            hold = robot.registers.hold
        await until(lambda: ur.controller.inputs[hold] == 1)
        await until(lambda: ur.controller.program.status & registers.STATUS_HELD != 0)


async def test_cancelled_calls_leave_nothing_half_done() -> None:
    async with bench(loopback_host()) as (_, robot):
        await robot.stop()
        async with robot._lock:
            resume = asyncio.create_task(robot.resume())
            await asyncio.sleep(0.01)
            resume.cancel()
            with pytest.raises(asyncio.CancelledError):
                await resume
        assert robot.status().motion_held  # the cancelled resume released nothing
        assert not robot._lock.locked()
        await robot.resume()
        correction = asyncio.create_task(robot.set_correction((0.01, 0.0, 0.0)))
        correction.cancel()
        with pytest.raises(asyncio.CancelledError):
            await correction
        sequence = await robot.set_correction((0.02, 0.0, 0.0))
        await until(lambda: robot.robot_state().accepted_sequence >= sequence)


async def test_a_connect_cancelled_while_waiting_for_the_controller() -> None:
    async def mute(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read()  # accepts, never answers
        writer.close()

    server = await asyncio.start_server(mute, "127.0.0.1", 0)  # a port of its own
    port = server.sockets[0].getsockname()[1]
    robot = URRobot(settings("127.0.0.1", rtde_port=port, ur_timeout_s=30.0))
    opening = asyncio.create_task(robot.__aenter__())
    await asyncio.sleep(0.1)
    opening.cancel()
    with pytest.raises(asyncio.CancelledError):
        await opening
    assert robot.status().link is LinkState.FAULT
    with pytest.raises((NotConnectedError, MotionHeldError)):
        await robot.set_correction((0.0, 0.0, 0.0))
    server.close()
    await server.wait_closed()
