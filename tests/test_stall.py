"""Issue 26: a stall is a fault within seconds. A move's reply timeout follows from the move
(drivers/move_timeout.py: its distance at the slowest speed, plus a margin), not
robot.move_timeout_s (60 s); the link and its status say "stalled"; the serial port is opened
exclusively and a second opener gets one line. Both C500C drivers over their emulators."""

from __future__ import annotations

import asyncio
import time

import pytest

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.errors import DeviceTimeoutError, NotConnectedError
from drivers.move_timeout import move_timeout_s
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config

#: the default cap (60 s) stays: only the move's own timeout may make the stall quick
SETTINGS = RobotSettings(
    command_timeout_s=1.0, move_margin_s=1.0, reconnect_max_backoff_s=0.2, heartbeat_s=0.25
)


def test_a_moves_timeout_follows_from_the_move() -> None:
    at = ((500.0, 0.0, 300.0), (0.0, 0.0, 0.0))
    step = ((500.001, 0.0, 300.0), (0.0, 0.0, 0.0))
    far = ((700.0, 0.0, 300.0), (0.0, 0.0, 0.0))
    assert move_timeout_s(SETTINGS, at, step, 100) == pytest.approx(1.0, abs=1e-3)
    # 200 mm at 30 % of 20 mm/s: 33 s of motion, plus the margin
    assert move_timeout_s(SETTINGS, at, far, 30) == pytest.approx(1.0 + 200 / 6.0)
    assert move_timeout_s(SETTINGS, None, step, 100) == SETTINGS.move_timeout_s  # unknown
    assert move_timeout_s(SETTINGS, at, far, 1) == SETTINGS.move_timeout_s  # capped


async def test_a_console_move_whose_finish_is_never_answered_is_a_stall_in_seconds() -> None:
    async with (
        C500CEmulator(EmulatorConfig(paced=False, move_ms=1.0)) as emulator,
        C500CRobot(SETTINGS, port=emulator.device_path, first_backoff_s=30.0) as robot,
    ):
        await robot.teach_goal()
        emulator.hold_answers("finish")  # the controller never answers the move's end
        began = time.monotonic()
        with pytest.raises(DeviceTimeoutError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        took_s = time.monotonic() - began
        assert took_s < SETTINGS.move_margin_s + 2 * SETTINGS.command_timeout_s + 5.0
        assert took_s < SETTINGS.move_timeout_s / 4
        status = robot.status()
        assert status.link is LinkState.STALLED and status.motion_held
        emulator.release_answers()


async def test_a_fast_path_move_never_answered_is_a_stall_in_seconds() -> None:
    config = server_emulator_config(paced=False, move_ms=1.0, silence_timeout_s=30.0)
    async with (
        C500CServerEmulator(config) as emulator,
        C500CServerRobot(SETTINGS, port=emulator.device_path, first_backoff_s=30.0) as robot,
    ):
        await robot.teach_goal()
        emulator.inject_server_fault("silence", 120.0)
        began = time.monotonic()
        with pytest.raises(DeviceTimeoutError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        took_s = time.monotonic() - began
        assert took_s < SETTINGS.move_margin_s + 5.0 < SETTINGS.move_timeout_s / 4
        status = robot.status()
        assert status.link is LinkState.STALLED and status.motion_held


async def test_a_second_opener_of_the_port_gets_one_line() -> None:
    async with (
        C500CEmulator(EmulatorConfig(paced=False, move_ms=1.0)) as emulator,
        C500CRobot(SETTINGS, port=emulator.device_path) as robot,
    ):
        await robot.teach_goal()
        with pytest.raises(NotConnectedError) as caught:
            async with C500CRobot(SETTINGS, port=emulator.device_path):
                pass
        message = str(caught.value)
        assert "in use by another process" in message and "\n" not in message
        await asyncio.sleep(0)
        await robot.actual_pose()  # the first owner's link is untouched


async def test_a_fast_path_move_whose_reply_never_comes_is_a_stall_in_seconds() -> None:
    """The program answers its heartbeats but the move's own reply does not come (a move
    that never ends): the link is alive, so only the move's timeout can see the stall. Before
    issue 26 this waited robot.move_timeout_s (60 s); the silent program above was caught by
    the heartbeats in about a second even then."""
    never_s = 4 * SETTINGS.move_timeout_s  # the emulated move ends long after the cap
    config = server_emulator_config(paced=False, move_ms=1000.0 * never_s)
    async with (
        C500CServerEmulator(config) as emulator,
        C500CServerRobot(SETTINGS, port=emulator.device_path, first_backoff_s=30.0) as robot,
    ):
        await robot.teach_goal()
        began = time.monotonic()
        with pytest.raises(DeviceTimeoutError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        took_s = time.monotonic() - began
        assert took_s < SETTINGS.move_margin_s + 5.0 < SETTINGS.move_timeout_s / 4
        status = robot.status()
        assert status.link is LinkState.STALLED and status.motion_held
