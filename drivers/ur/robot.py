"""The Universal Robots e-Series driver (``robot.driver = "ur-rtde"``, issue 31): a
drivers.base.OffsetRobot over RTDE, for a robot that plays its own taught program with
controller/ur/thermocomp_offset.script running beside it.

It streams the robot's state (joints, TCP pose and speed, joint temperatures, robot, safety
and program modes, and the program's registers: at which measured pose it is, which sequence
it accepted, its status, the offset it applies) at robot.rtde_frequency_hz, and writes the
correction, a sequence number and a hold flag into the input registers
(drivers/ur/registers.py) on every correction and at least every robot.ur_heartbeat_s.
Each package's joints, speeds and target accelerations go into a bounded log for a followed
run's motor heat (drivers/ur/motion.py, :meth:`URRobot.take_motion`).

**The hold** (drivers.base.Robot's contract, drivers/permit.py). :meth:`URRobot.stop` holds
from the moment it is called: the permit is held and the hold flag written to the controller
in the same synchronous step (one whole RTDE package into the socket, no await in between),
before anything else. Two input recipes keep the correction registers out of every package
but a correction's: the *hold recipe* (sequence, hold flag) carries the heartbeat, the hold
and the resume; the *correction recipe* (sequence, hold flag, the six target registers) only
:meth:`set_correction` and :meth:`apply_correction`, which read the permit right before the
write with no await between the check and the bytes: after a hold nothing is written into the
correction registers. Corrections are written one at a time (a lock), so a correction queued
behind one in flight meets the hold. Only :meth:`resume` with a ticket newer than the hold
releases it (the permit's generation: a hold that comes while a resume waits wins). The
controller echoes the sequence register in its output recipe: :meth:`resume` and
:meth:`follow_program` wait for that echo (the controller read the package), and
:meth:`apply_correction` for the program's acceptance (output register B+1): a program that
does not accept a correction within robot.command_timeout_s has stalled (held, link reported
``stalled`` until a resume). After :meth:`follow_program` (a run's start), a restart of the
offset program (it was seen stopped, or its accepted sequence went back) holds and refuses a
resume with GoalLostError: the program's offset state is gone.

What a hold means on a robot that plays its own program: the program's offset freezes where
it is; the program keeps playing. Pausing it is the Dashboard's ``pause``
(:meth:`URRobot.pause_program`), which a followed run sends *after* the hold, never before it
(daemon/run/followed/program_pause.py, robot.pause_program_on_hold): nothing here waits for
the Dashboard. The robot-side program freezes the offset by itself too when the PC goes
silent for its watchdog's 0.5 s.

A lost link (no state package for robot.ur_timeout_s, a closed or garbled connection) is a
fault: the correction is held, the link reconnects in the background (drivers/reconnect.py)
and stays held until an explicit resume. Nothing here moves the robot: the robot moves by its
own program; this driver only shifts that program's path within the program's limits.

**Holding a dwell for the cameras** (:meth:`URRobot.hold_dwell`): the frames register
(drivers/ur/registers.py) asks the program's ``tc_wait_for_frames`` to keep the arm at rest
on a measured pose while a loaded PC takes its frames (daemon/run/followed/measure.py). It
moves nothing, so it is written held or not; each connection starts with it at 0.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, Self

from config.settings import RobotSettings
from drivers.base import (
    ZERO_ROTATION,
    LinkState,
    OffsetRobotState,
    RobotDescription,
    RobotStatus,
    Vector3,
)
from drivers.errors import (
    DeviceError,
    DeviceTimeoutError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
)
from drivers.permit import MotionPermit, Ticket
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S, Reconnector
from drivers.ur import rtde_protocol as rtde
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.describe import describe_ur
from drivers.ur.motion import MotionLog, MotionSamples
from drivers.ur.registers import RegisterMap, wire_target
from drivers.ur.rtde_client import RtdeClient
from drivers.ur.rtde_protocol import Recipe, Value
from drivers.ur.state import (
    STATE_OUTPUTS,
    ProgramWatch,
    at_or_past,
    decode_state,
    next_sequence,
    state_modes,
)

logger = logging.getLogger(__name__)

DEVICE = "robot"


async def _done() -> None:
    """An awaitable that has nothing left to do."""


class URRobot:
    """A UR e-Series over RTDE (module docstring); an async context manager."""

    def __init__(
        self, settings: RobotSettings, *, first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S
    ) -> None:
        self.settings = settings
        self.registers = RegisterMap(settings.register_base)
        self.dashboard = DashboardClient(
            settings.host, settings.dashboard_port, settings.command_timeout_s
        )
        self._client: RtdeClient | None = None
        self._outputs: Recipe | None = None
        self._inputs: Recipe | None = None
        self._link = LinkState.DISCONNECTED
        self.permit = MotionPermit(DEVICE)  # the owner of "may the correction change"
        self._hold_inputs: Recipe | None = None
        self._corrections = asyncio.Lock()  # one correction at a time (module docstring)
        self._stalled = False  # the program stopped accepting corrections: until a resume
        self._program = ProgramWatch()  # a restart of the followed program (module docstring)
        self._seen_sequence = 0  # the sequence register as the controller reads it back
        self._seen_frames = 0  # the frames register as the controller reads it back
        self._frames_inputs: Recipe | None = None
        self._arrived = asyncio.Event()  # set (and replaced) on every state package
        self._last_error: str | None = None
        self._sequence = 0  # the last one written
        self._target: tuple[float, ...] = (0.0,) * 6  # the correction on the wire (m, rad)
        self._state: OffsetRobotState | None = None
        self.motion = MotionLog(settings.rtde_frequency_hz)  # for a followed run's motor heat
        self._lock = asyncio.Lock()  # resume and the reconnection, one at a time
        self._reader: asyncio.Task[None] | None = None
        self._heartbeat: asyncio.Task[None] | None = None
        self._reconnector = Reconnector(
            DEVICE,
            self._open_link,
            first_backoff_s=lambda: first_backoff_s,
            max_backoff_s=lambda: settings.reconnect_max_backoff_s,
            lock=self._lock,
            on_failure=lambda err: setattr(self, "_last_error", str(err)),
            task_name="ur-reconnect",
        )

    # -- the link ------------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        self._link = LinkState.CONNECTING
        try:
            await self._open_link()
        except BaseException:
            self._link = LinkState.FAULT
            raise
        self._heartbeat = asyncio.get_running_loop().create_task(
            self._heartbeat_loop(), name="ur-heartbeat"
        )
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._hold("closed", error=False)  # the program freezes the offset first
        await self._reconnector.cancel()
        for task in (self._heartbeat, self._reader):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._heartbeat = self._reader = None
        client, self._client = self._client, None
        if client is not None:
            await client.aclose()
        self._link = LinkState.DISCONNECTED

    async def _open_link(self) -> None:
        """Connect, set the recipes up, start, write the registers (the hold flag as it is)."""
        settings = self.settings
        client = RtdeClient(settings.host, settings.rtde_port, settings.ur_timeout_s)
        try:
            await client.connect()
            outputs = await client.setup_outputs(
                (
                    *STATE_OUTPUTS,
                    *self.registers.outputs,
                    self.registers.sequence,
                    self.registers.frames,
                ),
                settings.rtde_frequency_hz,
            )
            inputs = await client.setup_inputs(self.registers.inputs)
            hold_inputs = await client.setup_inputs(self.registers.hold_inputs)
            frames_inputs = await client.setup_inputs(self.registers.frames_inputs)
            await client.start()
        except BaseException:
            client.close()
            raise
        self._client, self._outputs, self._inputs = client, outputs, inputs
        self._hold_inputs, self._frames_inputs = hold_inputs, frames_inputs
        self._link = LinkState.CONNECTED
        self._write()
        self._write_frames(0)  # no frames in flight on a new link (module docstring)
        self._reader = asyncio.get_running_loop().create_task(
            self._read_loop(client, outputs), name="ur-rtde-reader"
        )
        logger.info(
            "UR %s connected (controller %s), registers from %d",
            settings.host,
            ".".join(map(str, client.controller_version or ())),
            self.registers.base,
        )

    async def _read_loop(self, client: RtdeClient, recipe: Recipe) -> None:
        try:
            while True:
                async with asyncio.timeout(self.settings.ur_timeout_s):
                    values = await client.read_data(recipe)
                self._state = state = decode_state(self.registers, recipe, values)
                self.motion.add_package(recipe, values)
                self._seen_sequence = int(values[-2])  # type: ignore[arg-type]
                self._seen_frames = int(values[-1])  # type: ignore[arg-type]
                lost = self._program.check(state)
                if lost is not None:
                    logger.warning("UR %s: correction held", lost)
                    self._hold(lost)
                self._wake()
        except (DeviceError, TimeoutError) as err:
            message = str(err) or f"no RTDE package for {self.settings.ur_timeout_s} s"
            self._link_fault(client, message)
            self._wake()

    def _wake(self) -> None:
        """Wake whatever waits for a state package (or for the link's end)."""
        arrived, self._arrived = self._arrived, asyncio.Event()
        arrived.set()

    def _link_fault(self, client: RtdeClient, message: str) -> None:
        if client is not self._client:
            return
        logger.warning("UR link lost (%s): correction held, reconnecting", message)
        self._hold(f"link lost: {message}")
        client.close()
        self._client = None
        self._link = LinkState.RECONNECTING
        self._reconnector.start()

    async def _heartbeat_loop(self) -> None:
        while True:
            await asyncio.sleep(self.settings.ur_heartbeat_s)
            if self._link is LinkState.CONNECTED:
                with contextlib.suppress(DeviceError):
                    self._write()

    # -- the registers -----------------------------------------------------------------------

    def _write(self, target: tuple[float, ...] | None = None) -> int:
        """One input package now: the next sequence and the hold flag, and with ``target``
        the correction registers (the correction recipe; else the hold recipe). Synchronous:
        no await, so nothing can come between a caller's check and these bytes."""
        client = self._client
        inputs = self._hold_inputs if target is None else self._inputs
        if client is None or inputs is None or not client.connected:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        sequence = next_sequence(self._sequence)
        values: list[Value] = [sequence, 1 if self.permit.held else 0]
        if target is not None:
            values.extend(target)
        client.send(rtde.data_package(inputs, values))
        self._sequence = sequence
        return sequence

    def _write_frames(self, pose: int) -> None:
        """The frames register now (the frames recipe: nothing else)."""
        client = self._client
        recipe = self._frames_inputs
        if client is None or recipe is None or not client.connected:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        client.send(rtde.data_package(recipe, [pose]))

    async def _until(self, reached: Callable[[], bool], what: str) -> None:
        """Wait for a state package after which ``reached()``; DeviceTimeoutError after
        robot.command_timeout_s, NotConnectedError when the link goes."""
        try:
            async with asyncio.timeout(self.settings.command_timeout_s):
                while not reached():
                    if self._link is not LinkState.CONNECTED:
                        raise NotConnectedError(DEVICE, f"link {self._link.value}: {what}")
                    await self._arrived.wait()
        except TimeoutError as err:
            raise DeviceTimeoutError(
                DEVICE, f"{what}: nothing within {self.settings.command_timeout_s} s"
            ) from err

    def _seen(self, sequence: int) -> Callable[[], bool]:
        return lambda: at_or_past(sequence, self._seen_sequence)

    def _accepted(self, sequence: int) -> Callable[[], bool]:
        def accepted() -> bool:
            state = self._state
            return state is not None and at_or_past(sequence, state.accepted_sequence)

        return accepted

    async def _exchange(self, what: str) -> None:
        """A heartbeat, and the controller's read-back of it (the hold recipe)."""
        self._require_link()
        await self._until(self._seen(self._write()), f"the controller did not read back {what}")

    def _checked(self, offset_mm: Vector3, rotation_rad: Vector3) -> tuple[float, ...]:
        limits = (self.settings.correction_limit_mm, self.settings.correction_limit_rad)
        return wire_target(offset_mm, rotation_rad, *limits, device=DEVICE)

    # -- the OffsetRobot protocol ------------------------------------------------------------

    def _require_link(self) -> None:
        if self._link is not LinkState.CONNECTED:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    def _write_correction(self, target: tuple[float, ...]) -> int:
        """The permit read right before the correction's bytes (no await in between)."""
        self.permit.require()
        self._require_link()
        sequence = self._write(target)
        self._target = target
        return sequence

    async def set_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        """Write the correction (mm and a rotation vector in rad, base frame); refused before
        any byte when not finite or over robot.correction_limit_*, when held or not connected.
        Returns the sequence it was written with (the program echoes it once accepted)."""
        target = self._checked(offset_mm, rotation_rad)
        async with self._corrections:
            sequence = self._write_correction(target)
            assert self._client is not None
            await self._client.drain()
            return sequence

    async def apply_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        """:meth:`set_correction`, then wait for the program to accept it (robot.
        command_timeout_s: else a stall, held). Cancelled while waiting: held, since the
        correction may be applied (as a cut move on the other drivers)."""
        target = self._checked(offset_mm, rotation_rad)
        async with self._corrections:
            sequence = self._write_correction(target)
            accepted = self._accepted(sequence)
            try:
                await self._until(
                    lambda: accepted() or self.permit.held,
                    f"the program did not accept correction {sequence}",
                )
            except DeviceTimeoutError as err:
                self._stalled = True
                self._hold(f"stalled: {err}")
                raise
            except asyncio.CancelledError:
                self._hold("a correction was cut before the program accepted it", error=False)
                raise
            if not accepted():  # a hold came first: the program froze its offset
                raise MotionHeldError(
                    DEVICE, f"held before the program accepted correction {sequence}"
                )
            return sequence

    async def read_state(self) -> OffsetRobotState:
        """The robot's state now: a heartbeat, and the first state package after the
        controller read it back (robot_state() is the last package received)."""
        await self._exchange("the heartbeat")
        return self.robot_state()

    async def follow_program(self) -> OffsetRobotState:
        """A run starts following the program as it is now (moves nothing; allowed while held):
        its restart from here on is a fault (module docstring). The controller reads back a
        heartbeat first."""
        async with self._lock:
            await self._exchange("the heartbeat")
            state = self.robot_state()
            self._program.follow(state)
            return state

    async def hold_dwell(self, pose: int) -> OffsetRobotState:
        """Ask the program to hold its dwell at measured pose ``pose`` (>= 1) while the PC
        takes its frames (module docstring), and return the first state package after the
        controller read the request back: its at-pose register says whether the program was
        still at that dwell (and so holds it). DeviceTimeoutError / NotConnectedError as
        :meth:`read_state`. Always follow with :meth:`release_dwell`."""
        if pose < 1:
            raise ValueError(f"a measured pose is 1 or more, not {pose}")
        self._require_link()
        self._write_frames(pose)
        await self._until(
            lambda: self._seen_frames == pose,
            f"the controller did not read back the frames request for pose {pose}",
        )
        return self.robot_state()

    def release_dwell(self) -> None:
        """The frames are taken: the program may leave its dwell (frames register 0). Never
        raises: without a link the program lets go by itself (its watchdog, its timeout)."""
        with contextlib.suppress(DeviceError, OSError):
            self._write_frames(0)

    def take_motion(self) -> MotionSamples:
        """The motion since the last take (drivers/ur/motion.py)."""
        return self.motion.take()

    def robot_state(self) -> OffsetRobotState:
        state = self._state
        if self._link is not LinkState.CONNECTED or state is None:
            raise NotConnectedError(DEVICE, f"no robot state ({self._link.value})")
        age = time.monotonic() - state.received_s
        if age > self.settings.ur_timeout_s:
            raise NotConnectedError(DEVICE, f"robot state {age:.2f} s old")
        return state

    def _hold(self, reason: str, *, error: bool = True) -> None:
        self.permit.hold(reason)  # first: from here no correction's bytes are written
        if error:
            self._last_error = reason
        with contextlib.suppress(DeviceError, OSError):
            self._write()  # the hold flag, now (a lost link: the program's watchdog freezes)

    def stop(self) -> Coroutine[Any, Any, None]:
        """Hold, from the moment this is called (module docstring). Awaiting it drains the
        hold's package to the socket."""
        self._hold("stopped by request", error=False)
        client = self._client
        return client.drain() if client is not None else _done()

    async def resume(self, ticket: Ticket | None = None) -> None:
        """Release a hold for the request that took ``ticket`` (None: now): the link must be
        up with a fresh state, the followed program must not have restarted (GoalLostError),
        and the controller reads back a heartbeat; a hold that came after the ticket wins
        (MotionHeldError, the hold stays). Then the hold flag is cleared."""
        ticket = ticket if ticket is not None else self.permit.ticket()
        async with self._lock:
            if not self.permit.is_current(ticket):
                self.permit.release(ticket)  # raises: a hold came after the request
            self.robot_state()  # NotConnectedError when the link is not up and fresh
            await self._exchange("the resume's heartbeat")  # a state from after this call
            if self._program.lost is not None:
                raise GoalLostError(
                    DEVICE,
                    f"the controller lost the taught goal: {self._program.lost}; start a new "
                    "run (it follows the program as it is)",
                )
            self.permit.release(ticket)  # MotionHeldError if a hold came meanwhile
            self._stalled = False
            self._write()  # the hold flag cleared
        logger.info("UR correction resumed")

    def status(self) -> RobotStatus:
        client = self._client
        extra = {
            "host": self.settings.host,
            "register_base": str(self.registers.base),
            "sequence": str(self._sequence),
            "reconnect_attempts": str(self._reconnector.attempts),
        }
        if client is not None and client.controller_version is not None:
            extra["controller_version"] = ".".join(map(str, client.controller_version))
            extra["bytes_sent"] = str(client.bytes_sent)
            extra["bytes_received"] = str(client.bytes_received)
        extra.update(state_modes(self._state))
        link = self._link
        if self._stalled and link is LinkState.CONNECTED:
            link = LinkState.STALLED
        return RobotStatus(
            link=link,
            motion_held=self.permit.held,
            last_error=self._last_error,
            hold_reason=self.permit.reason,
            extra=extra,
        )

    @property
    def controller_version(self) -> tuple[int, int, int, int] | None:
        """The controller's version (RTDE get_urcontrol_version), once connected."""
        client = self._client
        return None if client is None else client.controller_version

    async def describe(self) -> RobotDescription:
        """For ``thermocomp devices check`` (drivers/ur/describe.py)."""
        return await describe_ur(self)

    # -- the program (drivers.base.ProgramControl, through the Dashboard Server) -------------

    async def program_state(self) -> str:
        return await self.dashboard.program_state()

    async def pause_program(self) -> None:
        await self.dashboard.pause()

    async def play_program(self) -> None:
        await self.dashboard.play()
