"""What the daemon needs of each device: a Protocol per kind and the values they return.

Every implementation (real, replay, simulated) is an async context manager: entering opens
the device, leaving closes it whatever happened.
"""

from __future__ import annotations

import enum
from collections.abc import Coroutine
from dataclasses import dataclass, field
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

if TYPE_CHECKING:  # annotations only: `thermocomp <command> --help` loads no NumPy
    import numpy as np
    from numpy.typing import NDArray

from drivers.errors import DeviceError
from drivers.permit import MotionPermit, Ticket

Vector3 = tuple[float, float, float]


class AsyncDevice(Protocol):
    async def __aenter__(self) -> Self: ...

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None: ...


# --- camera ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera image. Pixel (row r, column c) has its centre at (x = c, y = r)."""

    image: NDArray[np.integer]  # 2-D, uint8 or uint16
    bit_depth: int  # significant bits (8, 12, 16)
    timestamp_s: float  # on the run clock (drivers.clock), when the exposure ended
    sequence: int  # 0, 1, 2 ... per opened camera
    #: what timestamp_s is: "camera" (the camera's clock + exposure), "trigger" (run clock at the
    #: software trigger + exposure), "backend" (the capture backend's stamp), "host" (when the
    #: driver received the frame: late by readout and transfer; issue 18)
    timestamp_source: str = "host"
    #: electrons per count of the sensor as the camera reports it, for the centroid's noise
    #: model; None: the camera does not say (GenICam's SFNC has no node for it: ``Gain`` is a
    #: relative dB figure), and the centroid measures it on the frame
    gain_e_per_count: float | None = None


class Camera(AsyncDevice, Protocol):
    async def grab(self) -> Frame:
        """The next frame; raises a DeviceError subclass when none can be had."""
        ...


# --- infrared reader -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RegionTemperature:
    name: str
    mean_c: float
    max_c: float
    node: str | None  # the model node this region measures, if any


@dataclass(frozen=True, slots=True)
class IrReading:
    regions: dict[str, RegionTemperature]
    timestamp_s: float  # on the run clock
    sequence: int
    frame_c: NDArray[np.floating] | None = None  # the thermal image in degC, when available


class IrReader(AsyncDevice, Protocol):
    async def read(self) -> IrReading: ...


# --- room thermometer (issue 29) --------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RoomReading:
    """The air's temperature where the arm stands (degC), when it was read (run clock), and
    which sensor read it."""

    temperature_c: float
    timestamp_s: float
    sensor: str


class RoomThermometer(AsyncDevice, Protocol):
    async def read(self) -> RoomReading: ...


# --- robot -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Pose:
    """A world pose as the C500C prints it: mm and degrees (WORLD row of `w2`)."""

    x: float
    y: float
    z: float
    z_rot: float = 0.0
    y_rot: float = 0.0
    x_rot: float = 0.0

    @property
    def position(self) -> Vector3:
        return (self.x, self.y, self.z)


#: The goal of a run that teaches one (every run before issue 20): the console's `opgoal`, the
#: fast path's goal 0.
DEFAULT_GOAL = "opgoal"
#: No rotation: a rotation vector (rad, base frame) of zero.
ZERO_ROTATION: Vector3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class MoveResult:
    requested_mm: Vector3  # the offset (or increment) asked for
    commanded_mm: Vector3  # what was sent: rounded to the console's 0.001 mm
    #: read back after the move finished; None when this move had no read-back (the console
    #: driver reads back every robot.readback_every-th move): then no pose may be recorded
    pose: Pose | None
    bytes_sent: int = 0
    bytes_received: int = 0
    #: each console command's time from being written to its prompt coming back (s)
    round_trips_s: tuple[float, ...] = ()
    #: the rotation sent with the move as the controller's z-rot, y-rot, x-rot (degrees, rounded
    #: as sent: 0.001 on the console, 0.0001 on the fast path); zeros for a translation only
    commanded_rotation_deg: Vector3 = (0.0, 0.0, 0.0)
    goal: str = DEFAULT_GOAL  # the taught goal the move was relative to (absolute moves)

    @property
    def read_back(self) -> bool:
        """Whether the pose was read back after this move."""
        return self.pose is not None

    @property
    def actual(self) -> Pose:
        """The read-back pose; a move without read-back raises instead of guessing one."""
        if self.pose is None:
            raise DeviceError("robot", "this move had no read-back (robot.readback_every)")
        return self.pose

    @property
    def rounding_mm(self) -> Vector3:
        c, r = self.commanded_mm, self.requested_mm
        return (c[0] - r[0], c[1] - r[1], c[2] - r[2])


class LinkState(enum.Enum):
    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    CONNECTED = "connected"
    AWAITING_POINT_OF_CONTROL = "awaiting-point-of-control"  # operator must press PAUSE/CONTINUE
    #: a command was cut (cancelled, timed out): the console is brought back to a clean prompt
    #: before the next command (Ctrl-E, then a probe line and its prompt)
    RESYNCHRONISING = "resynchronising"
    RECONNECTING = "reconnecting"
    #: a move's reply did not come within its own timeout (drivers/move_timeout.py): the link is
    #: reconnecting after a stall (reported by status() until it is connected again)
    STALLED = "stalled"
    FAULT = "fault"


@dataclass(frozen=True, slots=True)
class RobotStatus:
    link: LinkState
    arm_power: bool | None = None
    homed: bool | None = None
    online: bool | None = None
    point_of_control: bool | None = None
    motion_held: bool = False  # after a fault or a stop(): no motion until resume()
    last_error: str | None = None
    #: why motion is held ("stopped by request", the fault...); None when not held
    hold_reason: str | None = None
    extra: dict[str, str] = field(default_factory=dict)


class Robot(AsyncDevice, Protocol):
    """A robot link. Its ``permit`` (drivers/permit.py) is the one owner of "may the robot
    move": every hold goes through it, every motion command checks it under the driver's lock
    right before its bytes are written, and only a release with a ticket taken after the latest
    hold undoes a hold. tests/contract/ checks every driver and fake against this."""

    @property
    def permit(self) -> MotionPermit: ...

    async def teach_goal(self) -> Pose:
        """Remember the current pose as the operational goal (`here opgoal`)."""
        ...

    async def move_absolute(self, offset_mm: Vector3) -> MoveResult:
        """Move to goal + offset: the thesis's absolute location command (6.4.4)."""
        ...

    async def move_incremental(self, delta_mm: Vector3) -> MoveResult:
        """Move by delta from where the robot is (kept to reproduce the thesis)."""
        ...

    async def actual_pose(self) -> Pose: ...

    async def stop(self) -> None:
        """Hold: from the moment this is called (before its first await) the permit is held
        and every motion command is refused (MotionHeldError), checked under the driver's lock
        right before its bytes are written; it returns once no motion command can be written
        any more. What it does to a motion already under way depends on the link (see the
        driver). Only resume() releases a hold."""
        ...

    async def resume(self, ticket: Ticket | None = None) -> None:
        """Allow motion again after a hold or a fault (an explicit request, never automatic),
        on behalf of the request that took ``ticket`` when it arrived (None: now). A hold that
        came after the ticket wins: MotionHeldError, the hold stays. Raises GoalLostError when
        the controller no longer holds the taught goal: teach a new goal (teach_goal(), which
        moves nothing and is allowed while held) before resuming a new run."""
        ...

    def status(self) -> RobotStatus: ...


class GoalRobot(Robot, Protocol):
    """A robot with several named taught goals and 6-DOF absolute moves (issue 20: an arm's
    duty cycle teaches each of its poses once, then moves each time to "goal k + its own
    correction"). Both C500C drivers are one; the defaults give :class:`Robot`'s behaviour.
    The hold contract is Robot's: a hold refuses every motion, whatever the goal."""

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        """Remember the current pose as the taught goal ``goal`` (valid names:
        drivers/goals.py); teaching a name again replaces that goal only."""
        ...

    async def move_absolute(
        self,
        offset_mm: Vector3,
        rotation_rad: Vector3 = ZERO_ROTATION,
        *,
        goal: str = DEFAULT_GOAL,
    ) -> MoveResult:
        """Move to the taught ``goal`` shifted by ``offset_mm`` and turned by ``rotation_rad``
        (a rotation vector in the base frame, as daemon.arm.types.Pose6.rotation_rad; sent as
        the controller's z-y-x angles, Pose6.zyx_deg). Non-finite values are refused."""
        ...

    def taught_goals(self) -> dict[str, Pose]:
        """The goals taught on this connection's controller, by name."""
        ...


class SpeedGoalRobot(GoalRobot, Protocol):
    """A GoalRobot whose absolute moves also set the controller's speed (issue 20: a duty cycle
    plays each move at its pose's speed). The console driver is one (`speed N`,
    docs/reference/c500c-console.md "Motion and locations"); the fast path is not: its MOVE_GOAL
    frame carries no speed (controller/PROTOCOL.md), so an arm run does not play its duty cycle over
    it."""

    async def move_absolute(
        self,
        offset_mm: Vector3,
        rotation_rad: Vector3 = ZERO_ROTATION,
        *,
        goal: str = DEFAULT_GOAL,
        speed_percent: int | None = None,
    ) -> MoveResult:
        """GoalRobot.move_absolute at ``speed_percent`` (1..100 % of the controller's maximum
        speed; refused outside before anything is sent); None: the speed the controller has.
        The speed is sent only when it differs from the last one sent on this connection."""
        ...


# --- a robot that plays its own program (a UR over RTDE; run kind followed)
# -------------------------------------


@dataclass(frozen=True, slots=True)
class OffsetRobotState:
    """One state package of a robot that plays its own program (a UR over RTDE)."""

    timestamp_s: float  # the controller's clock (s since it started)
    received_s: float  # the host's monotonic clock when the package arrived
    joints_rad: tuple[float, ...]  # actual joint positions
    joint_speeds_rad_s: tuple[float, ...]
    #: actual TCP pose, base frame: x, y, z (mm) and a rotation vector (rad)
    tcp_pose: tuple[float, float, float, float, float, float]
    #: TCP speed, base frame: mm/s and rad/s
    tcp_speed: tuple[float, float, float, float, float, float]
    joint_temperatures_c: tuple[float, ...]
    robot_mode: int  # drivers.ur.modes.RobotMode
    safety_mode: int  # drivers.ur.modes.SafetyMode
    runtime_state: int  # drivers.ur.modes.RuntimeState (the program: playing, paused...)
    #: the program's "at measured pose" output: k (1-based pose of the taught cycle) while it
    #: dwells at a measured pose, 0 elsewhere
    at_pose: int
    #: what the robot-side program reports: the sequence it accepted, its status bits
    #: (drivers/ur/registers.py STATUS_*) and the offset it applies (mm, rad)
    accepted_sequence: int
    program_status: int
    applied_offset_mm: Vector3
    applied_rotation_rad: Vector3
    #: the program's instance (drivers/ur/registers.py): it changes when the program restarts
    program_instance: int = 0


@runtime_checkable
class OffsetRobot(AsyncDevice, Protocol):
    """A robot that runs its own taught program while the daemon corrects it with a 6-DOF
    offset (a UR with controller/ur/thermocomp_offset.script; daemon/run/followed/). The hold
    contract is Robot's: its ``permit`` (drivers/permit.py) is held by stop() before its first
    await and the robot-side program is told to freeze its offset; every correction is refused
    after a hold right before its bytes are written; only a resume() with a ticket newer than
    the hold releases it; a non-finite or over-limit correction is refused before any byte;
    after a link fault the correction stays held until resume()."""

    @property
    def permit(self) -> MotionPermit: ...

    async def set_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        """Write the correction (base frame: mm and a rotation vector in rad) for the program
        to follow; returns the sequence number it was written with."""
        ...

    def robot_state(self) -> OffsetRobotState:
        """The latest state package (NotConnectedError when there is none, or it is stale)."""
        ...

    async def follow_program(self) -> OffsetRobotState:
        """A run takes the program as it is now (moves nothing, allowed while held): a restart
        of the program from here on holds and refuses a resume (GoalLostError)."""
        ...

    def stop(self) -> Coroutine[Any, Any, None]:
        """Hold (see the class docstring): effective when called, awaiting it drains the
        hold's bytes."""
        ...

    async def resume(self, ticket: Ticket | None = None) -> None: ...

    def status(self) -> RobotStatus: ...


@runtime_checkable
class ProgramControl(Protocol):
    """A robot whose own program the PC can pause and play again (a UR's Dashboard Server:
    drivers/ur/dashboard_client.py). Each call raises DeviceError when the robot refuses or
    does not answer."""

    async def program_state(self) -> str:
        """``PLAYING``, ``PAUSED`` or ``STOPPED``."""
        ...

    async def pause_program(self) -> None: ...

    async def play_program(self) -> None: ...


@dataclass(frozen=True, slots=True)
class RobotDescription:
    """What a robot reports about itself for a bring-up check (``thermocomp devices check``):
    named facts in the order a person reads them, and each thing that would stop a run as
    (topic, one line)."""

    facts: tuple[tuple[str, str], ...]
    problems: tuple[tuple[str, str], ...] = ()


@runtime_checkable
class DescribedRobot(Protocol):
    """A robot that describes itself beyond its pose (a UR: drivers/ur/describe.py)."""

    async def describe(self) -> RobotDescription: ...
