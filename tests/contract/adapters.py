"""The robots under the Robot contract (tests/contract/test_robot_contract.py): every robot
driver over its emulator and every fake of the suite (tests/fakes.py FakeRobot and its
subclasses), each behind a small adapter that opens it and gives the suite its test hooks. A new
driver adds one adapter here and one entry in ADAPTERS (docs/how-to/add-a-robot-driver.md)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass
from typing import Any

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import server_protocol as server_proto
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.clock import VirtualClock
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from tests.fakes import FakeRobot, Gate
from tests.test_arm_run import ArmTruth, FakeArmRobot

#: Timeouts short enough for a stall to show in a test, long enough for a loaded machine.
SETTINGS = RobotSettings(
    command_timeout_s=3.0,
    move_margin_s=1.0,
    reconnect_max_backoff_s=0.2,
    heartbeat_s=0.25,
    server_silence_s=30.0,
)
RECONNECT_S = 20.0


@dataclass
class Subject:
    """A robot under the contract and what the suite may do to its link."""

    name: str
    robot: Any  # a drivers.base.GoalRobot
    written: Callable[[], int]  # motion commands that reached the robot's writer so far
    hold_replies: Callable[[], None]  # the next reply waits: a command is in flight
    reply_held: Callable[[], Awaitable[None]]  # ... until one does
    release_replies: Callable[[], None]
    stall_next_move: Callable[[], None]  # the next move's reply never comes
    drop_link: Callable[[], None]  # the link drops at the next exchange
    lose_goals: Callable[[], None]  # the controller restarts: its taught goals are gone
    reconnected: Callable[[], Awaitable[None]]  # the link is up again after a drop
    stall_budget_s: float  # a stalled move must fail within this


async def connected(robot: Any) -> None:
    """Wait until the robot's link is up again (a reconnection in the background)."""
    async with asyncio.timeout(RECONNECT_S):
        while robot.status().link is not LinkState.CONNECTED:  # noqa: ASYNC110 -- no event
            await asyncio.sleep(0.02)


@asynccontextmanager
async def console() -> AsyncIterator[Subject]:
    async with (
        C500CEmulator(EmulatorConfig(paced=False, move_ms=1.0)) as emulator,
        C500CRobot(SETTINGS, port=emulator.device_path, first_backoff_s=0.05) as robot,
    ):
        yield Subject(
            name="console",
            robot=robot,
            written=lambda: len(emulator.state.motion_commands()),
            hold_replies=emulator.hold_answers,
            reply_held=emulator.answer_held.wait,
            release_replies=emulator.release_answers,
            stall_next_move=lambda: emulator.hold_answers("finish"),
            drop_link=lambda: emulator.inject("close"),
            lose_goals=emulator.restart_controller,
            reconnected=lambda: robot.wait_link(LinkState.CONNECTED, RECONNECT_S),
            stall_budget_s=SETTINGS.move_margin_s + 2 * SETTINGS.command_timeout_s,
        )
        emulator.release_answers()


@asynccontextmanager
async def fast_path() -> AsyncIterator[Subject]:
    config = server_emulator_config(paced=False, move_ms=1.0, silence_timeout_s=30.0)
    moves = (server_proto.RequestType.MOVE_GOAL, server_proto.RequestType.MOVE_RELATIVE)
    async with (
        C500CServerEmulator(config) as emulator,
        C500CServerRobot(SETTINGS, port=emulator.device_path, first_backoff_s=0.05) as robot,
    ):

        def lose_goals() -> None:
            emulator.state.locations.clear()

        yield Subject(
            name="fast path",
            robot=robot,
            written=lambda: sum(r.type in moves for r in emulator.requests),
            hold_replies=emulator.hold_replies,
            reply_held=emulator.reply_held.wait,
            release_replies=emulator.release_replies,
            stall_next_move=lambda: emulator.inject_server_fault("silence", 60.0),
            drop_link=lambda: emulator.inject_server_fault("close"),
            lose_goals=lose_goals,
            reconnected=lambda: connected(robot),
            stall_budget_s=SETTINGS.move_margin_s + SETTINGS.command_timeout_s,
        )
        emulator.release_replies()


def fake() -> AbstractAsyncContextManager[Subject]:
    return _faked(FakeRobot(move_timeout_s=SETTINGS.move_margin_s), "fake")


def arm_fake() -> AbstractAsyncContextManager[Subject]:
    """The arm run's fake (tests/test_arm_run.py FakeArmRobot, the fake with the tool
    following its goals): a subclass must keep the contract too."""
    robot = FakeArmRobot(ArmTruth(VirtualClock()))
    robot.move_timeout_s = SETTINGS.move_margin_s
    return _faked(robot, "arm fake")


@asynccontextmanager
async def _faked(robot: FakeRobot, name: str) -> AsyncIterator[Subject]:
    gates: list[Gate] = []

    def hold_replies() -> None:
        robot.reply_gate = gate = Gate()
        gates.append(gate)

    async def reply_held() -> None:
        await gates[-1].reached.wait()

    def release_replies() -> None:
        for gate in gates:
            gate.open()

    async def reconnected() -> None:
        robot.link = LinkState.CONNECTED  # the fake's reconnection: at once

    async with robot:
        yield Subject(
            name=name,
            robot=robot,
            written=lambda: len(robot.commands),
            hold_replies=hold_replies,
            reply_held=reply_held,
            release_replies=release_replies,
            stall_next_move=lambda: robot.hung_moves.add(robot.moves),
            drop_link=robot.drop_link,
            lose_goals=robot.lose_goals,
            reconnected=reconnected,
            stall_budget_s=SETTINGS.move_margin_s,
        )
        release_replies()


#: Every robot the contract runs over: each driver over its emulator, and the suite's fake.
ADAPTERS: dict[str, Callable[[], AbstractAsyncContextManager[Subject]]] = {
    "console": console,
    "fast-path": fast_path,
    "fake": fake,
    "arm-fake": arm_fake,
}
