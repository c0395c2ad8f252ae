"""The CRS C500C controller's `ash` console over RS-232 (pyserial-asyncio): the robot driver.

Every exchange is one command line, its echo, its answer lines and a prompt
(drivers/c500c/protocol.py). Each command has a timeout; a garbled or missing reply is an error,
never a guess. The link under it (states, synchronisation, resynchronisation after a cut
command, reconnection, questions, the point-of-control wait) is drivers/c500c/link.py; this
module is what the daemon asks of a robot: teach, move (absolute from the taught goal, or
incremental), read the pose, hold, resume.

**The hold.** :meth:`C500CRobot.stop` holds motion from the instant it is called: every motion
command (`move`, `moves`, `wx`..., see ``c500c_protocol.MOTION_COMMANDS``) checks the hold under
the driver's lock immediately before its bytes are written, so a move queued behind another
command (a read-back, a teach, the reconnection) is refused with MotionHeldError. Only
:meth:`C500CRobot.resume` releases a hold. What a hold cannot do on this console: stop a motion
already written. `ash` has no known command that halts a motion in progress
(docs/reference/c500c-console.md), so the move under way (one small compensation step, `finish`ed
before the next) runs to its end; the controller-side fast-path program can halt (RAPL-3 `halt()`),
and the hardware E-stop remains the operator's way to stop the arm now. Likewise a motion command
waiting for the point of control moves the arm when the operator presses PAUSE/CONTINUE, even after
the driver gave up.

After a link fault the driver reconnects in the background, but sends no motion until the caller
explicitly resumes (a robot must never move on its own after something went wrong).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Coroutine
from typing import Any

from config.settings import RobotSettings
from drivers.base import (
    DEFAULT_GOAL,
    ZERO_ROTATION,
    LinkState,
    MoveResult,
    Pose,
    RobotStatus,
    Vector3,
)
from drivers.c500c import protocol as proto
from drivers.c500c.console import Transcript
from drivers.c500c.link import DEVICE, TARGET_LOCATION, ConsoleLink
from drivers.c500c.link_states import LINK_UP
from drivers.errors import (
    DeviceError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
    ProtocolError,
)
from drivers.goals import goal_variable, require_target, rotation_zyx_deg
from drivers.move_timeout import move_timeout_s
from drivers.permit import MotionPermit, Ticket
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S

logger = logging.getLogger(__name__)

#: A read-back farther than this from the commanded goal is not believed (mm): ten times the
#: A465's +-0.05 mm repeatability (thesis 3.2.1), so only a garbled table can exceed it.
READBACK_TOLERANCE_MM = 0.5


async def _done() -> None:
    """An awaitable that has nothing left to do."""


class C500CRobot(ConsoleLink):
    """The robot as the daemon sees it (drivers.base.Robot) on a C500C console."""

    #: a drivers.base.SpeedGoalRobot: its moves take a speed (`speed N`)
    SETS_SPEED = True

    def __init__(
        self,
        settings: RobotSettings,
        *,
        port: str | None = None,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
        transcript: Transcript | None = None,
        prepare: bool = True,
        permit: MotionPermit | None = None,
    ) -> None:
        super().__init__(
            settings,
            port=port,
            first_backoff_s=first_backoff_s,
            transcript=transcript,
            prepare=prepare,
            permit=permit,
        )
        if not prepare:  # a check: nothing may move (silently: nothing went wrong)
            self.permit.hold("connected to check only")
        self._goals: dict[str, Pose] = {}  # taught goals by name (drivers/goals.py)
        self._moves = 0  # moves since the goal was taught (robot.readback_every counts them)
        #: the speed (%) last set with `speed N` on this connection; None: unknown (the
        #: controller's own: after a connect, a resume or a restart), so the next is sent
        self._speed_percent: int | None = None
        #: where the tool was last read or sent (position mm, z-y-x angles deg): a move's
        #: timeout follows from its distance from here (drivers/move_timeout.py)
        self._at: tuple[Vector3, Vector3] | None = None

    async def _read_pose(self) -> Pose:
        lines = await self._command("w2", self.settings.command_timeout_s)
        try:
            pose = proto.parse_world_pose(lines)
        except ProtocolError as err:
            self._link_fault(err)
            raise
        self._at = (pose.position, (pose.z_rot, pose.y_rot, pose.x_rot))
        return pose

    # --- the Robot protocol ---

    def _require_motion_allowed(self) -> None:
        """A quick refusal before waiting for the lock; the binding check is in _exchange."""
        self.permit.require()
        if self._link not in (LinkState.CONNECTED, LinkState.RESYNCHRONISING):
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        """`new <var>`, `here <var>`, then `w2`, with <var> the goal's location variable
        (`opgoal` for the default goal, `g_<name>` for the others: drivers/goals.py): moves
        nothing, so it is allowed while held. The variable is made with `new` the first time
        it is taught (docs/reference/c500c-console.md "Questions": `here` to an unknown name would
        ask)."""
        variable = goal_variable(goal, DEVICE)
        async with self._lock:
            await self._create_variable(variable)
            await self._command(f"here {variable}", self.settings.command_timeout_s)
            pose = self._goals[goal] = await self._read_pose()
            self._moves = 0
        logger.info("goal %s taught at %s", goal, pose)
        return pose

    def taught_goals(self) -> dict[str, Pose]:
        return dict(self._goals)

    def _readback_due(self) -> bool:
        return self._moves % self.settings.readback_every == 0

    async def _run_motion(
        self,
        writes: list[proto.Write],
        requested: Vector3,
        commanded: Vector3,
        expected: Vector3 | None,
        *,
        rotation_deg: Vector3 = (0.0, 0.0, 0.0),
        goal: str = DEFAULT_GOAL,
        target: tuple[Vector3, Vector3] | None = None,
        speed_percent: int | None = None,
    ) -> MoveResult:
        """The writes of one move (the last is the `w2` read-back when ``expected`` is given);
        called with the lock held. ``target``: where the move goes (position, angles), for its
        timeout (drivers/move_timeout.py); None: unknown (robot.move_timeout_s)."""
        finish_timeout_s = (
            self.settings.move_timeout_s
            if target is None
            else move_timeout_s(self.settings, self._at, target, speed_percent)
        )
        sent0, received0 = self.counters.sent, self.counters.received
        round_trips_s: list[float] = []
        actual: Pose | None = None
        try:
            for write in writes:
                timeout_s = (
                    finish_timeout_s if "finish" in write else self.settings.command_timeout_s
                )
                if write == ("w2",):
                    actual = await self._read_pose()
                else:
                    await self._exchange(write, timeout_s)
                round_trips_s.append(self._last_round_trip_s)
        except MotionHeldError:
            raise
        except DeviceError as err:
            self._hold(str(err))
            raise
        except asyncio.CancelledError:
            # a move cut anywhere in its exchange holds, as on the fast path: the caller
            # cannot know how far it got (tests/contract/)
            self._hold("a move was cut before its answer")
            raise
        if actual is None and target is not None:
            self._at = target  # no read-back: where it was sent
        self._moves += 1
        self._arm_power, self._homed = True, True
        self._point_of_control = True
        if actual is not None and expected is not None:
            worst = max(abs(a - e) for a, e in zip(actual.position, expected, strict=True))
            if worst > READBACK_TOLERANCE_MM:
                error = ProtocolError(
                    DEVICE, f"read-back {actual.position} is {worst:.3f} mm from {expected}"
                )
                self._link_fault(error)
                raise error
        return MoveResult(
            requested_mm=requested,
            commanded_mm=commanded,
            pose=actual,
            bytes_sent=self.counters.sent - sent0,
            bytes_received=self.counters.received - received0,
            round_trips_s=tuple(round_trips_s),
            commanded_rotation_deg=rotation_deg,
            goal=goal,
        )

    @staticmethod
    def _require_finite(values_mm: Vector3) -> None:
        """Last guard before the serial writer (issue 10): the daemon checks every target, but
        a NaN or an infinity would otherwise be printed into a console command as "nan"."""
        require_target(values_mm, "motion target", DEVICE)

    async def move_absolute(
        self,
        offset_mm: Vector3,
        rotation_rad: Vector3 = ZERO_ROTATION,
        *,
        goal: str = DEFAULT_GOAL,
        speed_percent: int | None = None,
    ) -> MoveResult:
        """Goal + offset (thesis 6.4.4): `set cur = <goal>` and `wshift cur,dx,dy,dz,zrot,yrot,
        xrot` in one write, `moves`, `finish`, and the `w2` read-back every
        robot.readback_every-th move. ``rotation_rad``: a rotation vector in the base frame
        (daemon.arm.types.Pose6), sent as its z-y-x angles in degrees with 3 decimals
        (docs/reference/c500c-console.md; drivers/goals.py). The read-back is checked on the
        position only: how the controller composes wshift's angles with the goal's is not documented
        (docs/reference/c500c-console.md).

        ``speed_percent`` (SpeedGoalRobot): `speed N` first, in the same write as `set` and
        `wshift`, only when N differs from the speed last sent (it moves nothing; a hold that
        comes after it still refuses the `moves`). Outside 1..100 it is refused here, before
        anything is written."""
        self._require_finite(offset_mm)
        speed = None
        if speed_percent is not None:
            try:
                speed = proto.speed_command(speed_percent)
            except ValueError as err:
                raise DeviceError(DEVICE, f"refused {err}") from err
        rotation_deg = rotation_zyx_deg(rotation_rad, DEVICE)
        variable = goal_variable(goal, DEVICE)
        taught = self._goals.get(goal)
        if taught is None:
            raise DeviceError(DEVICE, f"no goal {goal!r} taught: call teach_goal() first")
        self._require_motion_allowed()
        async with self._lock:
            # again under the lock: a hold that came while this waited sends nothing of the move
            self._require_motion_allowed()
            readback = self._readback_due()
            writes, commanded = proto.absolute_move_commands(
                offset_mm,
                online=self.settings.online,
                goal=variable,
                target=TARGET_LOCATION,
                readback=readback,
                rotation_deg=rotation_deg,
            )
            if speed is not None and speed_percent != self._speed_percent:
                writes[0] = (speed, *writes[0])
            else:
                speed = None
            expected = (taught.x + commanded[0], taught.y + commanded[1], taught.z + commanded[2])
            turned = (
                taught.z_rot + rotation_deg[0],
                taught.y_rot + rotation_deg[1],
                taught.x_rot + rotation_deg[2],
            )
            if speed is not None:
                # unknown until the write is answered: a failed write sends it again
                self._speed_percent = None
            result = await self._run_motion(
                writes,
                offset_mm,
                commanded,
                expected,
                rotation_deg=(
                    proto.round_deg(rotation_deg[0]),
                    proto.round_deg(rotation_deg[1]),
                    proto.round_deg(rotation_deg[2]),
                ),
                goal=goal,
                target=(expected, turned),
                speed_percent=speed_percent if speed_percent is not None else self._speed_percent,
            )
            if speed_percent is not None:
                self._speed_percent = speed_percent
            return result

    async def move_incremental(self, delta_mm: Vector3) -> MoveResult:
        """Relative `wx`/`wy`/`wz` moves (only to reproduce the thesis's comparison)."""
        self._require_finite(delta_mm)
        self._require_motion_allowed()
        async with self._lock:
            self._require_motion_allowed()
            readback = self._readback_due()
            writes, commanded = proto.incremental_move_commands(delta_mm, readback=readback)
            expected: Vector3 | None = None
            if readback:
                start = await self._read_pose()
                expected = (start.x + commanded[0], start.y + commanded[1], start.z + commanded[2])
            target = None
            if self._at is not None:
                (x, y, z), angles = self._at
                target = ((x + commanded[0], y + commanded[1], z + commanded[2]), angles)
            return await self._run_motion(
                writes,
                delta_mm,
                commanded,
                expected,
                target=target,
                speed_percent=self._speed_percent,
            )

    async def read_position_lines(self) -> list[str]:
        """The raw lines of one `w2` read-out (``thermocomp robot check`` prints them)."""
        async with self._lock:
            return await self._command("w2", self.settings.command_timeout_s)

    async def actual_pose(self) -> Pose:
        async with self._lock:
            return await self._read_pose()

    def stop(self) -> Coroutine[Any, Any, None]:
        """Hold, from the moment this is called: the hold is set here, before the coroutine
        is even awaited (a task that runs ``stop()`` later still holds at once). Awaiting it
        returns at once, since no motion command can be written any more: each one checks the
        hold under the lock right before its bytes are written. A motion already written runs
        to its end: the console has no known halt command (module docstring; the E-stop
        remains). Not an error: ``last_error`` is left alone, ``hold_reason`` says why."""
        self._hold("stopped by request", error=False)
        return _done()

    async def resume(self, ticket: Ticket | None = None) -> None:
        """Allow motion again, for the request that took ``ticket`` (None: now). The link
        must be up; the console is checked first: every taught goal must still exist on the
        controller (`set cur = <goal>` each), else GoalLostError and the hold stays; then a `w2`.

        A lost goal is not re-created from the recorded pose: the console's read-out has only
        0.001 mm and no arm configuration (stance) for it, and after a restart the calibration
        it was taught in may be gone, so a goal rebuilt that way could differ from the taught
        one without anything showing it (docs/reference/c500c-console.md); teaching it again is the
        operator's call.

        A hold that came after the ticket wins: the hold stays and MotionHeldError is raised
        (drivers/permit.py)."""
        ticket = ticket if ticket is not None else self.permit.ticket()
        async with self._lock:
            if not self.permit.is_current(ticket):
                self.permit.release(ticket)  # raises: a hold came after the request
            if self._link not in LINK_UP:
                raise NotConnectedError(DEVICE, f"cannot resume while {self._link.value}")
            for goal in self._goals:
                try:
                    await self._command(
                        f"set {TARGET_LOCATION} = {goal_variable(goal, DEVICE)}",
                        self.settings.command_timeout_s,
                    )
                except GoalLostError as err:
                    self._last_error = str(err)
                    raise
            await self._read_pose()
            self.permit.release(ticket)  # MotionHeldError if a hold came meanwhile
            if self._link is LinkState.AWAITING_POINT_OF_CONTROL:
                self._enter(LinkState.CONNECTED)
            self._point_of_control = None  # unknown until the next motion command
            self._moves = 0  # the first move after a resume reads the pose back
            self._speed_percent = None  # a restarted controller is back at its own speed
        logger.info("robot motion resumed")

    def status(self) -> RobotStatus:
        return RobotStatus(
            link=self._reported_link(),
            arm_power=self._arm_power,
            homed=self._homed,
            online=self._online,
            point_of_control=self._point_of_control,
            motion_held=self.permit.held,
            last_error=self._last_error,
            hold_reason=self.permit.reason,
            extra={
                "port": self.port,
                "application": self.settings.application,
                "prompt": self._last_prompt,
                "reconnect_attempts": str(self._reconnect_attempts),
                "resyncs": str(self._resyncs),
                "readback_every": str(self.settings.readback_every),
                "bytes_sent": str(self.bytes_sent),
                "bytes_received": str(self.bytes_received),
            },
        )

    @property
    def bytes_sent(self) -> int:
        return self.counters.sent

    @property
    def bytes_received(self) -> int:
        return self.counters.received

    @property
    def goal(self) -> Pose | None:
        """The default goal (`opgoal`), if taught."""
        return self._goals.get(DEFAULT_GOAL)
