"""Test doubles of drivers/base.py for the daemon's tests, and the harness that runs a Daemon
on them.

The fake bench's physical truth is a second ThermalModel of the same network with the same
heat, so with a noise-free robot the compensated spot must stay put (the analytic oracle).
The fake robot locks like the real driver (drivers/c500c/robot.py): one command at a time under one
lock, the hold checked under the lock right before a motion command is "written", so a move
queued behind another command is refused once a hold came (issue 15). Gates let a test stop a
device inside a call (``robot.pose_gate``, ``camera.gate``) to act during a step.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np

from config import Settings
from daemon.arm.types import Pose6
from daemon.model import ThermalModel, load_network
from daemon.run.states import RunParameters
from daemon.service import Daemon
from daemon.vision import render_spot
from drivers.base import (
    DEFAULT_GOAL,
    ZERO_ROTATION,
    Frame,
    IrReading,
    LinkState,
    MoveResult,
    OffsetRobotState,
    Pose,
    RegionTemperature,
    RobotStatus,
    Vector3,
)
from drivers.clock import Clock, make_clock
from drivers.errors import DeviceError, DeviceTimeoutError, GoalLostError, NotConnectedError
from drivers.goals import require_finite, require_target
from drivers.permit import MotionPermit, Ticket
from drivers.ur.modes import RobotMode, RuntimeState, SafetyMode


class Gate:
    """Holds a device call until the test opens it; says when a call is waiting at it."""

    def __init__(self) -> None:
        self.reached = asyncio.Event()
        self._open = asyncio.Event()
        self.error: DeviceError | None = None  # raised by the call once opened, if set

    async def pass_through(self) -> None:
        self.reached.set()
        await self._open.wait()
        if self.error is not None:
            raise self.error

    def open(self, error: DeviceError | None = None) -> None:
        self.error = error
        self._open.set()


HEAT_W = {"2": 5.0, "9": 5.0}  # ~35 um in the first minute: big enough to see
UM_PER_PX = (10.22, 9.72)
SHAPE = (120, 160)  # small frames keep the suite fast
GOAL = Pose(500.0, 0.0, 300.0)
SLOW_MOVE_S = 0.07  # 3.5 periods of the 20 ms step of the overrun test


class FakeBench:
    """The truth: the same network and heat as the controller's model."""

    def __init__(self, clock: Clock, heat_w: dict[str, float]) -> None:
        self.clock = clock
        self.truth = ThermalModel(load_network("thesis-two-link"), "exact", 1.0, 22.0)
        self.truth.set_heat(heat_w)
        self.robot_offset_mm = np.zeros(3)

    def spot_um(self) -> np.ndarray:
        self.truth.advance_to(max(self.clock.now(), self.truth.time_s))
        return self.truth.deformation_um() + 1000.0 * self.robot_offset_mm


class FakeRobot:
    """The one hand-written robot of the daemon's tests: a GoalRobot (named goals, 6-DOF
    absolute moves) that passes the Robot contract suite (tests/contract/), as the drivers do.

    It locks like drivers/c500c/robot.py: one command at a time under one lock, the permit
    (drivers/permit.py) checked under the lock right before a motion command is "written"
    (``commands``), so a move queued behind another command is refused once a hold came. Its
    test hooks: ``reply_gate`` (the next command waits there, holding the lock: a command in
    flight), ``pose_gate``/``resume_gate`` (one call waits), ``fail_moves``/``slow_moves``/
    ``hung_moves`` by move number (a hung move is a stall: DeviceTimeoutError after
    ``move_timeout_s``, the link ``stalled``), ``held_moves`` (a hold comes right before that
    move is written), ``drop_link()``, ``lose_goals()``. With ``clock`` and ``move_s`` a move
    takes that long on the clock, holding the lock as a driver waits for its end;
    ``sets_speed``: moves take a speed (drivers/base.py SpeedGoalRobot, as the console
    driver), else none (as the fast path's)."""

    def __init__(
        self,
        bench: FakeBench | None = None,
        *,
        move_timeout_s: float = 2.0,
        clock: Clock | None = None,
        move_s: float = 0.0,
        sets_speed: bool = False,
    ) -> None:
        self.bench = bench
        self.clock = clock
        self.move_s = move_s
        self.SETS_SPEED = sets_speed  # daemon/run/arm/robot.py sets_speed reads it
        self.speeds: list[int | None] = []  # each written move's speed (None: the default)
        self.permit = MotionPermit()
        self.commands: list[tuple[str, Vector3]] = []  # motion commands "written"
        self.written: list[tuple[str, Pose6]] = []  # ... as (goal, correction)
        self.taught: dict[str, Pose] = {}
        self.goal: str | None = None  # the goal and correction of the last move
        self.correction = Pose6.zero()
        self.fail_moves: set[int] = set()  # move numbers (0-based) that time out
        self.slow_moves: set[int] = set()  # move numbers that take SLOW_MOVE_S of real time
        self.hung_moves: set[int] = set()  # move numbers whose reply never comes (a stall)
        self.held_moves: set[int] = set()  # move numbers refused by a hold that comes first
        self.hanging = asyncio.Event()
        self.position_errors_um: dict[int, float] = {}  # move number -> x error of that move
        self.move_timeout_s = move_timeout_s
        self.resumes = 0
        self.pose_reads = 0
        self.moves = 0
        self.lock = asyncio.Lock()  # one command at a time, as the real driver
        self.reply_gate: Gate | None = None  # set: the next command waits there, under the lock
        self.pose_gate: Gate | None = None  # set: actual_pose() waits there, holding the lock
        self.resume_gate: Gate | None = None  # set: resume() waits there before releasing
        self.move_gate: Gate | None = None  # set: the next move waits there before the lock
        self.resume_error: DeviceError | None = None  # raised by resume()
        self.moves_waiting = 0  # motion calls waiting for the lock
        self.link = LinkState.CONNECTED
        self._goals_lost = False

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    # --- test hooks ---

    def drop_link(self) -> None:
        """The link drops: motion held, every command fails until resume() (a reconnection)."""
        self.link = LinkState.RECONNECTING
        self.permit.hold("robot: link closed")

    def lose_goals(self) -> None:
        """The controller restarted: it forgot every taught goal."""
        self._goals_lost = True

    async def _reply(self) -> None:
        gate, self.reply_gate = self.reply_gate, None
        if gate is not None:
            await gate.pass_through()
        if self.link is not LinkState.CONNECTED:
            raise NotConnectedError("robot", f"not connected ({self.link.value})")

    # --- the Robot protocol ---

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        async with self.lock:
            await self._reply()
            if self.bench is not None:
                self.bench.robot_offset_mm = np.zeros(3)
            self.taught[goal] = self._pose()
            return self.taught[goal]

    def taught_goals(self) -> dict[str, Pose]:
        return dict(self.taught)

    def _check(self) -> None:
        """Right before a motion command is written, under the lock (drivers/c500c/robot.py)."""
        move = self.moves
        self.moves += 1
        if move in self.held_moves:
            self.permit.hold(f"held before move {move}")
        self.permit.require()
        if move in self.fail_moves:
            self.permit.hold(f"no answer to move {move}")
            raise DeviceTimeoutError("robot", f"no answer to move {move}")

    def _result(self, requested: Vector3, goal: str = DEFAULT_GOAL) -> MoveResult:
        return MoveResult(requested, requested, self._pose(), goal=goal)

    def _pose(self) -> Pose:
        offset = np.zeros(3) if self.bench is None else self.bench.robot_offset_mm
        return Pose(GOAL.x + offset[0], GOAL.y + offset[1], GOAL.z + offset[2])

    async def move_absolute(
        self,
        offset_mm: Vector3,
        rotation_rad: Vector3 = ZERO_ROTATION,
        *,
        goal: str = DEFAULT_GOAL,
        speed_percent: int | None = None,
    ) -> MoveResult:
        if speed_percent is not None and not self.SETS_SPEED:
            raise TypeError("this robot's moves take no speed")  # as a driver without one
        require_target(offset_mm, "motion target", "robot")
        require_finite(rotation_rad, "rotation", "robot")
        if goal not in self.taught:
            raise DeviceError("robot", f"no goal {goal!r} taught: call teach_goal() first")
        gate, self.move_gate = self.move_gate, None
        if gate is not None:
            await gate.pass_through()
        self.moves_waiting += 1
        try:
            await self.lock.acquire()
        finally:
            self.moves_waiting -= 1
        try:
            try:
                await self._reply()
            except asyncio.CancelledError:  # cut on its way to the writer: held, as drivers
                self.permit.hold("a move was cut before its reply")
                raise
            if self.moves in self.slow_moves:
                await asyncio.sleep(SLOW_MOVE_S)
            hung = self.moves in self.hung_moves
            self._check()
            self.commands.append(("absolute", offset_mm))
            correction = Pose6(np.asarray(offset_mm, float), np.asarray(rotation_rad, float))
            self.written.append((goal, correction))
            self.speeds.append(speed_percent)
            if hung:
                await self._stall()
            if self.clock is not None and self.move_s > 0.0:
                await self.clock.sleep_until(self.clock.now() + self.move_s)
            self.goal, self.correction = goal, correction
            self._moved(np.asarray(offset_mm, float), goal)
            return self._result(offset_mm, goal)
        finally:
            self.lock.release()

    async def _stall(self) -> None:
        """The move's reply never comes: a timeout, motion held, the link stalled."""
        self.hanging.set()
        try:
            async with asyncio.timeout(self.move_timeout_s):
                await asyncio.Event().wait()  # a controller that never answers
        except TimeoutError as err:
            self.permit.hold("robot: no answer to the move")
            self.link = LinkState.STALLED
            raise DeviceTimeoutError("robot", "no answer to the move") from err

    def _moved(self, offset_mm: np.ndarray, goal: str) -> None:
        """Where the move took the tool (the two-link bench's truth follows it)."""
        if self.bench is not None:
            error_mm = self.position_errors_um.get(self.moves - 1, 0.0) / 1000.0
            self.bench.robot_offset_mm = offset_mm + np.array([error_mm, 0.0, 0.0])

    async def move_incremental(self, delta_mm: Vector3) -> MoveResult:
        require_target(delta_mm, "motion target", "robot")
        async with self.lock:
            await self._reply()
            self._check()
            self.commands.append(("incremental", delta_mm))
            if self.bench is not None:
                self.bench.robot_offset_mm = self.bench.robot_offset_mm + np.asarray(delta_mm)
            return self._result(delta_mm)

    async def actual_pose(self) -> Pose:
        async with self.lock:
            await self._reply()
            self.pose_reads += 1
            if self.pose_gate is not None:
                await self.pose_gate.pass_through()
            return self._pose()

    @property
    def held(self) -> bool:
        return self.permit.held

    async def stop(self) -> None:
        self.permit.hold("stopped by request")  # at once, before any await

    async def resume(self, ticket: Ticket | None = None) -> None:
        ticket = ticket if ticket is not None else self.permit.ticket()
        async with self.lock:
            if self.link is LinkState.RECONNECTING:
                self.link = LinkState.CONNECTED  # it reconnected meanwhile
            await self._reply()
            if self.resume_gate is not None:
                await self.resume_gate.pass_through()
            if self.resume_error is not None:
                raise self.resume_error
            if self._goals_lost and self.taught:
                raise GoalLostError("robot", "controller restarted")
            self.link = LinkState.CONNECTED
            self.permit.release(ticket)
            self.resumes += 1

    def status(self) -> RobotStatus:
        return RobotStatus(self.link, motion_held=self.permit.held, hold_reason=self.permit.reason)


class FakeOffsetRobot(FakeRobot):
    """A robot that plays its own program (drivers/base.py OffsetRobot, the followed run's
    robot) built on the suite's FakeRobot, so it keeps the same Robot contract
    (tests/contract/, adapter ``offset-fake``): a correction is a move to the program's one
    goal (the lock, the permit checked right before it is "written", the refusals, the stall,
    the cut), taking the program is teaching that goal (moves nothing, allowed while held), a
    restarted program is a lost goal (a resume refused), and the state package is the fake's
    pose. The program is playing from the start: its goal is there before any call."""

    #: a UR5e at a pose of its program, its joints warmer than the 22 degC room
    JOINTS_RAD = (0.0, -1.745, 1.745, -1.571, -1.571, 0.0)
    JOINT_TEMPERATURES_C = (30.0, 34.0, 31.0, 28.0, 27.0, 26.0)

    def __init__(self, *, move_timeout_s: float = 2.0) -> None:
        super().__init__(move_timeout_s=move_timeout_s)
        self.taught[DEFAULT_GOAL] = self._pose()  # the program plays: its path is its goal
        self.at_pose = 1
        self.followed = 0  # follow_program() calls

    async def set_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        await self.move_absolute(offset_mm, rotation_rad)
        return len(self.commands)  # the sequence it was written with

    async def apply_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        """As drivers/ur/robot.py: written and accepted (the fake's program accepts at once)."""
        return await self.set_correction(offset_mm, rotation_rad)

    def robot_state(self) -> OffsetRobotState:
        if self.link is not LinkState.CONNECTED:
            raise NotConnectedError("robot", f"no robot state ({self.link.value})")
        pose, t, r = self._pose(), self.correction.translation_mm, self.correction.rotation_rad
        offset = (float(t[0]), float(t[1]), float(t[2]))
        return OffsetRobotState(
            timestamp_s=0.0,
            received_s=0.0,
            joints_rad=self.JOINTS_RAD,
            joint_speeds_rad_s=(0.0,) * 6,
            tcp_pose=(pose.x + offset[0], pose.y + offset[1], pose.z + offset[2], 0.0, 3.14, 0.0),
            tcp_speed=(0.0,) * 6,
            joint_temperatures_c=self.JOINT_TEMPERATURES_C,
            robot_mode=RobotMode.RUNNING,
            safety_mode=SafetyMode.NORMAL,
            runtime_state=RuntimeState.PLAYING,
            at_pose=self.at_pose,
            accepted_sequence=len(self.commands),
            program_status=0,
            applied_offset_mm=offset,
            applied_rotation_rad=(float(r[0]), float(r[1]), float(r[2])),
        )

    async def read_state(self) -> OffsetRobotState:
        """As drivers/ur/robot.py: an exchange with the controller, then its state."""
        await self.actual_pose()
        return self.robot_state()

    async def follow_program(self) -> OffsetRobotState:
        """The run takes the program as it is: its goal taught where it stands (moves
        nothing); a restart from here on refuses the resume (FakeRobot.lose_goals)."""
        await self.teach_goal()
        self.followed += 1
        return self.robot_state()


class FakeCamera:
    def __init__(self, bench: FakeBench) -> None:
        self.bench = bench
        self.sequence = 0
        self.age_s = 0.0
        self.gates: dict[int, Gate] = {}  # grab number (0 = the reference frame) -> gate
        # as the sim camera, it reports its sensor's gain; None: as a GenICam camera
        self.gain_e_per_count: float | None = 1.0

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Frame:
        gate = self.gates.get(self.sequence)
        if gate is not None:
            await gate.pass_through()
        spot = self.bench.spot_um()
        centre = (80.0 + spot[0] / UM_PER_PX[0], 60.0 + spot[1] / UM_PER_PX[1])
        image = render_spot(shape=SHAPE, centre_xy=centre, sigma_px=3.0, bit_depth=16)
        self.sequence += 1
        # stamped at its exposure, as the sim camera: the fake knows the time exactly
        timestamp_s = self.bench.clock.now() - self.age_s
        return Frame(
            image,
            16,
            timestamp_s,
            self.sequence,
            timestamp_source="camera",
            gain_e_per_count=self.gain_e_per_count,
        )


class FakeIr:
    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.reads = 0
        self.gates: dict[int, Gate] = {}  # read number (0 = the first) -> gate

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def read(self) -> IrReading:
        gate = self.gates.get(self.reads)
        self.reads += 1
        if gate is not None:
            await gate.pass_through()
        region = RegionTemperature("shaft", 25.0, 26.5, "9")
        return IrReading({"shaft": region}, self.clock.now(), 0)


class OpenedDevices:
    """A fake's devices as an async context manager with nothing to open or close (the
    daemon's open_devices hook enters it; the arm's fakes use it too)."""

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        return None


class FakeDevices(OpenedDevices):
    def __init__(self, clock: Clock, heat_w: dict[str, float]) -> None:
        self.truth = FakeBench(clock, heat_w)  # not `bench`: that is the real sim's hook
        self.robot = FakeRobot(self.truth)
        self.camera = FakeCamera(self.truth)
        self.ir = FakeIr(clock)


async def stop_with_a_move_in_flight(
    daemon: Daemon, robot: FakeRobot, timeout_s: float = 60.0
) -> dict[str, Any]:
    """Stop the run while its next move waits on its way to the robot (a gate), the race a
    loaded machine makes by chance: the stop's hold comes first, then the move goes on and is
    refused. Returns the stop's answer."""
    gate = Gate()
    robot.move_gate = gate
    async with asyncio.timeout(timeout_s):
        await gate.reached.wait()
        stopping = asyncio.create_task(daemon.stop())
        while not robot.held:  # noqa: ASYNC110 -- the fake's permit has no event
            await asyncio.sleep(0.001)
        gate.open()
        return await stopping


def make_settings(tmp_path: Path, **sections: dict[str, Any]) -> Settings:
    data: dict[str, Any] = {
        "storage": {"data_dir": str(tmp_path), "report_at_end": False},
        "camera": {"width_px": SHAPE[1], "height_px": SHAPE[0], "um_per_px": UM_PER_PX},
        "model": {"heat_w": HEAT_W},
        # no real-time scheduling for the suite's daemons (tests/conftest.py says why)
        "scheduler": {"duration_s": 60.0, "step_s": 1.0, "realtime_priority": 0},
    }
    for name, values in sections.items():
        data[name] = {**data.get(name, {}), **values}
    return Settings.model_validate(data)


class Harness:
    def __init__(self, settings: Settings) -> None:
        self.clock = make_clock(settings.bench.clock, settings.bench.time_factor)
        self.devices: FakeDevices | None = None
        self.daemon = Daemon(settings, clock=self.clock, open_devices=self._open)
        #: what the camera reports of its sensor's gain (None: nothing, as GenICam)
        self.camera_gain_e_per_count: float | None = 1.0

    def _open(self, settings: Settings, clock: Clock) -> FakeDevices:
        self.devices = FakeDevices(clock, dict(settings.model.heat_w))
        self.devices.camera.gain_e_per_count = self.camera_gain_e_per_count
        return self.devices

    @property
    def robot(self) -> FakeRobot:
        assert self.devices is not None
        return self.devices.robot

    @property
    def camera(self) -> FakeCamera:
        assert self.devices is not None
        return self.devices.camera

    @property
    def ir(self) -> FakeIr:
        assert self.devices is not None
        return self.devices.ir


def params(settings: Settings, **overrides: Any) -> RunParameters:
    return RunParameters.from_settings(settings, **overrides)
