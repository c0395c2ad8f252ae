"""The fast path: the robot driver for controller/thermocomp_server.r3, the RAPL-3 program that
serves the binary protocol of controller/PROTOCOL.md on the controller's second serial port
(the link itself: drivers/c500c/server_link.py).

One step is one MOVE_GOAL frame out and one reply in (68 bytes, ~6 ms of line at 115200) instead
of the console's five commands and its `w2` table (docs/reference/c500c-console.md "The fast path").
A hold writes HOLD at once, even while a move awaits its reply: the program polls the port during
the move and halt()s it, and the move is answered with catalogue 044.
"""

from __future__ import annotations

import asyncio
import logging
import time

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
from drivers.c500c import protocol as console_proto
from drivers.c500c import server_protocol as proto
from drivers.c500c.robot import READBACK_TOLERANCE_MM
from drivers.c500c.server_link import DEVICE, ServerLink
from drivers.errors import (
    DeviceError,
    DeviceReportedError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)
from drivers.goals import MAX_MOVE_OFFSET_MM, check_goal_name, require_target, rotation_zyx_deg
from drivers.move_timeout import move_timeout_s
from drivers.permit import MotionPermit, Ticket
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S

logger = logging.getLogger(__name__)

#: The farthest offset a MOVE frame carries (mm): the drivers' bound, or the int32 of 0.1 um
#: counts (controller/PROTOCOL.md), whichever is smaller.
MAX_FRAME_OFFSET_MM = min(MAX_MOVE_OFFSET_MM, (2**31 - 1) / proto.COUNTS_PER_MM)
#: Catalogue 044 (docs/reference/c500c-console.md); the console's table of texts may not carry it.
HALT_TEXT = "Halt() command invoked"


def status_text(code: int) -> str:
    if code == proto.Status.HALTED:
        return HALT_TEXT
    if code in proto.STATUS_TEXTS:
        return proto.STATUS_TEXTS[code]
    return console_proto.MOTION_ERRORS.get(code, "controller error")


def _pose(values: proto.Pose6) -> Pose:
    return Pose(*values)


class C500CServerRobot(ServerLink):
    """The robot (drivers.base.Robot) through the thermocomp server program on the C500C."""

    def __init__(
        self,
        settings: RobotSettings,
        *,
        port: str | None = None,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
        permit: MotionPermit | None = None,
    ) -> None:
        super().__init__(settings, port=port, first_backoff_s=first_backoff_s, permit=permit)
        self._motion_lock = asyncio.Lock()  # one motion at a time (the program refuses two)
        # taught goals by name, each with its index in the program (the default goal is 0)
        self._goals: dict[str, tuple[int, Pose]] = {}
        self._arm_power: bool | None = None
        self._homed: bool | None = None
        #: where the tool was last read (position mm, z-y-x angles deg): a move's timeout
        #: follows from its distance from here (drivers/move_timeout.py)
        self._at: tuple[Vector3, Vector3] | None = None

    def _check(self, reply: proto.Reply, *, motion: bool) -> proto.Reply:
        """Raise the controller's error, if any (catalogue numbers passed through)."""
        pose = reply.pose
        self._at = ((pose[0], pose[1], pose[2]), (pose[3], pose[4], pose[5]))
        if reply.ok:
            if motion:
                self._arm_power, self._homed = True, True
            return reply
        code = reply.status
        if code == 7:
            self._arm_power = False
        elif code == 5:
            self._homed = False
        text = status_text(code)
        if code == proto.Status.HELD:
            self._hold("the controller program refused motion: held")
            raise MotionHeldError(DEVICE, f"the controller program holds motion: {text}")
        if code == proto.Status.NO_CONTROL:
            raise PointOfControlError(
                DEVICE, console_proto.POINT_OF_CONTROL_MESSAGE + " (restart the program)"
            )
        raise DeviceReportedError(DEVICE, code if code < proto.Status.NO_GOAL else None, text)

    # --- the Robot protocol ---

    def _goal_index(self, goal: str) -> int:
        """The program's index of ``goal``: the default goal is 0 (a single goal's frames are
        those of before issue 20), the others get 1, 2 ... in the order first taught."""
        check_goal_name(goal, DEVICE)
        known = self._goals.get(goal)
        if known is not None:
            return known[0]
        if goal == DEFAULT_GOAL:
            return 0
        used = {index for index, _ in self._goals.values()}
        free = [i for i in range(1, proto.MAX_GOALS) if i not in used]
        if not free:
            raise DeviceError(DEVICE, f"the program holds {proto.MAX_GOALS} goals at most")
        return free[0]

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        """TEACH_GOAL with the goal's index: the program does here() into that goal."""
        index = self._goal_index(goal)
        reply = await self._request(
            proto.RequestType.TEACH_GOAL, timeout_s=self.settings.command_timeout_s, goal=index
        )
        pose = _pose(self._check(reply, motion=False).pose)
        self._goals[goal] = (index, pose)
        logger.info("goal %s (#%d) taught at %s", goal, index, pose)
        return pose

    def taught_goals(self) -> dict[str, Pose]:
        return {name: pose for name, (_, pose) in self._goals.items()}

    async def _move(
        self,
        request_type: proto.RequestType,
        offset: Vector3,
        expected_from: Pose,
        exchanges_before: int = 0,
        *,
        rotation_deg: Vector3 = (0.0, 0.0, 0.0),
        goal: str = DEFAULT_GOAL,
        goal_index: int = 0,
    ) -> MoveResult:
        """One motion frame and its reply; ``exchanges_before``: plain requests this step
        made first (counted in the step's bytes: other traffic such as heartbeats is not)."""
        require_target(offset, "motion target", DEVICE, MAX_FRAME_OFFSET_MM)
        self._require_motion_allowed()
        offset6 = proto.quantise((*offset, *rotation_deg))
        commanded = (offset6[0], offset6[1], offset6[2])
        base = expected_from
        target = (
            (base.x + offset6[0], base.y + offset6[1], base.z + offset6[2]),
            (base.z_rot + offset6[3], base.y_rot + offset6[4], base.x_rot + offset6[5]),
        )
        timeout_s = move_timeout_s(self.settings, self._at, target)  # its frame has no speed
        async with self._motion_lock:
            started = time.perf_counter()
            try:
                reply = self._check(
                    await self._request(
                        request_type,
                        offset6,
                        timeout_s=timeout_s,
                        goal=goal_index,
                    ),
                    motion=True,
                )
            except DeviceError as err:
                self._hold(str(err))
                raise
            except asyncio.CancelledError:
                # the frame may be on the wire: the program may move; hold until a resume
                # (the console driver holds a cut move likewise; tests/contract/)
                self._hold("a move was cut before its reply")
                raise
            round_trip_s = time.perf_counter() - started
        actual = _pose(reply.pose)
        expected = tuple(e + c for e, c in zip(expected_from.position, commanded, strict=True))
        worst = max(abs(a - e) for a, e in zip(actual.position, expected, strict=True))
        if worst > READBACK_TOLERANCE_MM:
            error = ProtocolError(
                DEVICE, f"pose {actual.position} is {worst:.4f} mm from {expected}"
            )
            self._link_fault(error)
            raise error
        return MoveResult(
            offset,
            commanded,
            actual,  # every reply carries the pose: the fast path reads back every step
            bytes_sent=proto.MOVE_REQUEST_BYTES
            + (proto.GOAL_INDEX.size if goal_index else 0)
            + exchanges_before * proto.REQUEST_BYTES,
            bytes_received=(1 + exchanges_before) * proto.REPLY_BYTES,
            round_trips_s=(round_trip_s,),
            commanded_rotation_deg=(offset6[3], offset6[4], offset6[5]),
            goal=goal,
        )

    async def move_absolute(
        self,
        offset_mm: Vector3,
        rotation_rad: Vector3 = ZERO_ROTATION,
        *,
        goal: str = DEFAULT_GOAL,
    ) -> MoveResult:
        """Goal + offset in one frame (thesis 6.4.4): the program shifts the goal by the six
        values (x, y, z mm; z-rot, y-rot, x-rot degrees: ``rotation_rad``, a rotation vector in
        the base frame, as its z-y-x angles, drivers/goals.py), moves, waits for the end of the
        motion and answers the actual pose. The read-back is checked on the position."""
        require_target(offset_mm, "motion target", DEVICE, MAX_FRAME_OFFSET_MM)
        rotation_deg = rotation_zyx_deg(rotation_rad, DEVICE)
        check_goal_name(goal, DEVICE)
        taught = self._goals.get(goal)
        if taught is None:
            raise DeviceError(DEVICE, f"no goal {goal!r} taught: call teach_goal() first")
        index, pose = taught
        return await self._move(
            proto.RequestType.MOVE_GOAL,
            offset_mm,
            pose,
            rotation_deg=rotation_deg,
            goal=goal,
            goal_index=index,
        )

    async def move_incremental(self, delta_mm: Vector3) -> MoveResult:
        """The actual pose + delta (only to reproduce the thesis's comparison)."""
        self._require_motion_allowed()
        start = await self.actual_pose()
        return await self._move(proto.RequestType.MOVE_RELATIVE, delta_mm, start, 1)

    async def actual_pose(self) -> Pose:
        reply = await self._request(
            proto.RequestType.READ_POSE, timeout_s=self.settings.command_timeout_s
        )
        return _pose(self._check(reply, motion=False).pose)

    async def stop(self) -> None:
        """Hold now (synchronously, before any await: no motion frame can be written from here
        on), then send HOLD — not queued behind a move awaiting its reply — so the program
        halt()s a motion in progress. A link that is down cannot carry it: the program's silence
        timeout halts the arm instead."""
        self._hold("stopped by request", error=False)
        try:
            self._check(
                await self._request(
                    proto.RequestType.HOLD, timeout_s=self.settings.command_timeout_s
                ),
                motion=False,
            )
        except DeviceError as err:
            logger.warning("HOLD not acknowledged (%s); the program's silence timeout halts", err)

    async def resume(self, ticket: Ticket | None = None) -> None:
        """Allow motion again: the link must be up and the program must still hold the goal
        taught (it forgets it when restarted); then RELEASE. A hold that comes while this runs
        wins: MotionHeldError, and the hold stays: RELEASE is not written for a ticket older
        than the latest hold (checked under the write lock), and a HOLD that comes after it is
        written after it (drivers/permit.py)."""
        ticket = ticket if ticket is not None else self.permit.ticket()
        if self._link is not LinkState.CONNECTED:
            raise NotConnectedError(DEVICE, f"cannot resume while {self._link.value}")
        reply = self._check(
            await self._request(
                proto.RequestType.READ_POSE, timeout_s=self.settings.command_timeout_s
            ),
            motion=False,
        )
        if self._goals and not reply.flags & proto.Flag.GOAL_TAUGHT:
            raise GoalLostError(DEVICE, "program restarted?")
        self._check(
            await self._request(
                proto.RequestType.RELEASE,
                timeout_s=self.settings.command_timeout_s,
                ticket=ticket,
            ),
            motion=False,
        )
        self.permit.release(ticket)  # MotionHeldError if a hold came meanwhile
        logger.info("robot motion resumed")

    def status(self) -> RobotStatus:
        flags = self._flags
        return RobotStatus(
            link=self._reported_link(),
            arm_power=self._arm_power,
            homed=self._homed,
            online=self.settings.online,
            point_of_control=None if flags is None else bool(flags & proto.Flag.POINT_OF_CONTROL),
            motion_held=self.permit.held,
            last_error=self._last_error,
            hold_reason=self.permit.reason,
            extra={
                "port": self.port,
                "program": "thermocomp_server",
                "reconnect_attempts": str(self._reconnect_attempts),
                "bytes_sent": str(self._bytes_sent),
                "bytes_received": str(self._bytes_received),
                "controller_flags": "" if flags is None else str(int(flags)),
            },
        )

    @property
    def goal(self) -> Pose | None:
        """The default goal, if taught."""
        taught = self._goals.get(DEFAULT_GOAL)
        return None if taught is None else taught[1]
