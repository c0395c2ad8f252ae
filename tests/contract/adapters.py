"""The robots under the Robot contract (tests/contract/test_robot_contract.py): every robot
driver over its emulator and every fake of the suite (tests/fakes.py FakeRobot and its
subclasses: CONTRACT_FAKES), each behind a small adapter that opens it and gives the suite its
test hooks. A new driver adds one adapter here and one entry in ADAPTERS (docs/how-to/
add-a-robot-driver.md); a new fake subclasses FakeRobot, gets an adapter and an entry in
CONTRACT_FAKES (tests/contract/test_no_other_fakes.py refuses a robot-like class anywhere
else in tests/)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from config.settings import RobotSettings
from drivers.base import (
    DEFAULT_GOAL,
    ZERO_ROTATION,
    LinkState,
    OffsetRobotState,
    Pose,
    RobotStatus,
    Vector3,
)
from drivers.c500c import server_protocol as server_proto
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.clock import VirtualClock
from drivers.errors import DeviceError
from drivers.permit import MotionPermit, Ticket
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from drivers.sim.ur.emulator import UREmulator
from drivers.ur.robot import URRobot
from tests.fakes import FakeOffsetRobot, FakeRobot, Gate
from tests.fakes_arm import ArmTruth, FakeArmRobot

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
    """The arm run's fake (tests/fakes_arm.py FakeArmRobot, the fake with the tool
    following its goals): a subclass must keep the contract too."""
    robot = FakeArmRobot(ArmTruth(VirtualClock()))
    robot.move_timeout_s = SETTINGS.move_margin_s
    return _faked(robot, "arm fake")


def offset_fake() -> AbstractAsyncContextManager[Subject]:
    """The followed run's fake (tests/fakes.py FakeOffsetRobot), through the same calls as the
    UR's (OffsetUnderContract)."""
    robot = FakeOffsetRobot(move_timeout_s=SETTINGS.move_margin_s)
    return _faked(robot, "offset fake", OffsetUnderContract(robot))


@asynccontextmanager
async def _faked(robot: FakeRobot, name: str, facade: Any = None) -> AsyncIterator[Subject]:
    """``robot`` under the contract, called directly or through ``facade``."""
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
            robot=robot if facade is None else facade,
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


class CheckedOffsetRobot(Protocol):
    """An OffsetRobot (drivers/base.py) with the two calls that wait for the controller, as
    URRobot has them: a correction the program accepted, the state after an exchange."""

    @property
    def permit(self) -> MotionPermit: ...

    async def follow_program(self) -> OffsetRobotState: ...

    async def apply_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int: ...

    async def read_state(self) -> OffsetRobotState: ...

    async def stop(self) -> None: ...

    async def resume(self, ticket: Ticket | None = None) -> None: ...

    def status(self) -> RobotStatus: ...


class OffsetUnderContract:
    """A robot that plays its own program (an OffsetRobot: the UR of drivers/ur/robot.py, the
    fake of tests/fakes.py) under the Robot contract's calls: its one "goal" is the path of
    its own program, a "move" is a correction the program accepted (apply_correction),
    teaching is follow_program (moves nothing) and the pose is read after an exchange with
    the controller. The hold, the permit, the refusals and the link are the robot's own,
    untouched."""

    def __init__(self, robot: CheckedOffsetRobot) -> None:
        self.robot = robot
        self.permit = robot.permit

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        self._goal(goal)
        state = await self.robot.follow_program()
        return Pose(*state.tcp_pose[:3])

    async def move_absolute(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION, *, goal: str = DEFAULT_GOAL
    ) -> int:
        self._goal(goal)
        return await self.robot.apply_correction(offset_mm, rotation_rad)

    async def actual_pose(self) -> Pose:
        state = await self.robot.read_state()
        return Pose(*state.tcp_pose[:3])

    async def stop(self) -> None:
        await self.robot.stop()

    async def resume(self, ticket: Ticket | None = None) -> None:
        await self.robot.resume(ticket)

    def status(self) -> Any:
        return self.robot.status()

    @staticmethod
    def _goal(goal: str) -> None:
        if goal != DEFAULT_GOAL:
            raise DeviceError("robot", f"no goal {goal!r}: a UR follows its own program's path")


#: The UR's timeouts: a reply withheld by a test is released well before the link times out.
UR_SETTINGS = RobotSettings(
    driver="ur-rtde",
    host="127.0.0.1",
    command_timeout_s=SETTINGS.command_timeout_s,
    reconnect_max_backoff_s=0.2,
    rtde_frequency_hz=125.0,
    ur_timeout_s=10.0,
)


@asynccontextmanager
async def universal_robots() -> AsyncIterator[Subject]:
    async with UREmulator(host="127.0.0.1", rtde_port=0, dashboard_port=0) as ur:
        settings = UR_SETTINGS.model_copy(
            update={"rtde_port": ur.rtde_port, "dashboard_port": ur.dashboard_port}
        )
        async with URRobot(settings, first_backoff_s=0.05) as robot:
            controller = ur.controller
            target = controller.registers.target[0]

            def hold_replies() -> None:
                ur.rtde.input_withheld.clear()
                ur.rtde.withhold = True

            def release_replies() -> None:
                ur.rtde.withhold = False
                controller.program_frozen = False

            def lose_goals() -> None:  # the operator stops the program and plays it again
                controller.stop(ur.now())
                controller.play(ur.now())

            def stall_next_move() -> None:
                controller.program_frozen = True

            yield Subject(
                name="universal-robots",
                robot=OffsetUnderContract(robot),
                written=lambda: controller.writes[target],
                hold_replies=hold_replies,
                reply_held=ur.rtde.input_withheld.wait,
                release_replies=release_replies,
                stall_next_move=stall_next_move,
                drop_link=ur.drop_connections,
                lose_goals=lose_goals,
                reconnected=lambda: connected(robot),
                stall_budget_s=UR_SETTINGS.command_timeout_s,
            )
            release_replies()


#: Every robot the contract runs over: each driver over its emulator, and the suite's fake.
ADAPTERS: dict[str, Callable[[], AbstractAsyncContextManager[Subject]]] = {
    "console": console,
    "fast-path": fast_path,
    "fake": fake,
    "arm-fake": arm_fake,
    "offset-fake": offset_fake,
    "universal-robots": universal_robots,
}

#: The suite's robot fakes, each under the contract above: the only robot-like classes the
#: tests may define (tests/contract/test_no_other_fakes.py).
CONTRACT_FAKES: tuple[type, ...] = (FakeRobot, FakeArmRobot, FakeOffsetRobot)
