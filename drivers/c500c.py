"""The CRS C500C controller's `ash` console over RS-232 (pyserial-asyncio): the robot driver.

Every exchange is one command line, its echo, its answer lines and the prompt
(drivers/c500c_protocol.py). Each command has a timeout; a garbled or missing reply is an error,
never a guess. After a link fault (timeout, garbled reply, lost port) the driver reconnects in
the background with a capped exponential backoff, but it sends no further motion until the
caller explicitly calls :meth:`C500CRobot.resume` (a robot must never move on its own after
something went wrong). Link states (drivers.base.LinkState):

    DISCONNECTED --__aenter__--> CONNECTING --handshake ok--> CONNECTED
    CONNECTED --link fault--> RECONNECTING --attempt ok--> CONNECTED (motion held)
    RECONNECTING --attempt fails--> wait backoff, try again (first 0.5 s, x2, capped)
    CONNECTED --"Press the PAUSE/CONTINUE..."--> AWAITING_POINT_OF_CONTROL --resume()--> CONNECTED
    any --__aexit__--> DISCONNECTED
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

import serial
import serial_asyncio

from config.settings import RobotSettings
from drivers import c500c_protocol as proto
from drivers.base import LinkState, MoveResult, Pose, RobotStatus, Vector3
from drivers.errors import (
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    MotionHeldError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)

logger = logging.getLogger(__name__)

DEVICE = proto.DEVICE
#: First wait before a reconnection attempt (s); doubles per failed attempt up to the
#: configured cap (robot.reconnect_max_backoff_s).
RECONNECT_FIRST_BACKOFF_S = 0.5
RECONNECT_BACKOFF_FACTOR = 2.0
#: After Ctrl-E, the console is considered settled once it has been silent this long (s).
HANDSHAKE_QUIET_S = 0.05
#: A read-back farther than this from the commanded goal is not believed (mm): ten times the
#: A465's +-0.05 mm repeatability (thesis 3.2.1), so only a garbled table can exceed it.
READBACK_TOLERANCE_MM = 0.5
#: Name of the taught operational goal and of the per-step target on the controller.
GOAL_LOCATION = "opgoal"
TARGET_LOCATION = "cur"


#: The link's state machine: every allowed transition (drivers.base.LinkState). FAULT is not
#: used here: a broken link is RECONNECTING, a device-reported fault holds motion instead.
TRANSITIONS: dict[LinkState, frozenset[LinkState]] = {
    LinkState.DISCONNECTED: frozenset({LinkState.CONNECTING}),
    LinkState.CONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
    LinkState.CONNECTED: frozenset(
        {LinkState.AWAITING_POINT_OF_CONTROL, LinkState.RECONNECTING, LinkState.DISCONNECTED}
    ),
    LinkState.AWAITING_POINT_OF_CONTROL: frozenset(
        {LinkState.CONNECTED, LinkState.RECONNECTING, LinkState.DISCONNECTED}
    ),
    LinkState.RECONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
}


class _LinkLost(Exception):
    """The port closed or failed under us (internal; surfaces as NotConnectedError)."""


@dataclass
class _Connection:
    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter

    def close(self) -> None:
        transport = self.writer.transport
        if not transport.is_closing():  # a lost port has already closed its transport
            transport.abort()


class C500CRobot:
    """The robot as the daemon sees it (drivers.base.Robot) on a C500C console."""

    def __init__(
        self,
        settings: RobotSettings,
        *,
        port: str | None = None,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
    ) -> None:
        self.settings = settings
        self.port = port if port is not None else settings.port
        self.first_backoff_s = first_backoff_s
        self._prompt = proto.prompt_for(settings.application)
        self._connection: _Connection | None = None
        self._lock = asyncio.Lock()
        self._link = LinkState.DISCONNECTED
        self.link_history: list[LinkState] = [self._link]  # every state entered, in order
        self._motion_held = False
        self._last_error: str | None = None
        self._goal: Pose | None = None
        self._arm_power: bool | None = None
        self._homed: bool | None = None
        self._online: bool | None = None
        self._point_of_control: bool | None = None
        self._reconnect_task: asyncio.Task[None] | None = None
        self._reconnect_attempts = 0
        self._connected_event = asyncio.Event()
        self._bytes_sent = 0
        self._bytes_received = 0
        self._last_round_trip_s = math.nan  # of the latest command answered

    # --- lifecycle ---

    def _enter(self, state: LinkState) -> None:
        """Take one transition of the state machine (TRANSITIONS); staying put is a no-op."""
        if state is self._link:
            return
        if state not in TRANSITIONS[self._link]:
            raise RuntimeError(f"C500C link: no transition {self._link.value} -> {state.value}")
        logger.debug("C500C link: %s -> %s", self._link.value, state.value)
        self._link = state
        self.link_history.append(state)

    async def __aenter__(self) -> Self:
        self._enter(LinkState.CONNECTING)
        try:
            await self._connect()
        except BaseException:
            await self._close()
            raise
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self._close()

    async def _close(self) -> None:
        task, self._reconnect_task = self._reconnect_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._drop_connection()
        self._enter(LinkState.DISCONNECTED)
        self._connected_event.clear()

    async def _open_port(self) -> _Connection:
        settings = self.settings

        def open_blocking() -> Any:
            # Opening a port can block (USB adapters, termios): never on the event loop.
            return serial.serial_for_url(
                self.port,
                baudrate=settings.baudrate,
                bytesize=settings.bytesize,
                parity=settings.parity,
                stopbits=settings.stopbits,
                rtscts=False,  # C500C.md: RTS/CTS does not work on the console
                xonxoff=False,
                timeout=0,
            )

        try:
            instance = await asyncio.to_thread(open_blocking)
        except (serial.SerialException, OSError, ValueError) as err:
            raise NotConnectedError(DEVICE, f"cannot open {self.port}: {err}") from err
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        protocol = asyncio.StreamReaderProtocol(reader)
        transport, _ = await serial_asyncio.connection_for_serial(loop, lambda: protocol, instance)
        return _Connection(reader, asyncio.StreamWriter(transport, protocol, reader, loop))

    async def _connect(self) -> None:
        """Open the port and get a clean `ash` prompt (C500C.md: Ctrl-E first)."""
        connection = await self._open_port()
        self._connection = connection
        try:
            await self._handshake(connection)
            self._enter(LinkState.CONNECTED)
            self._connected_event.set()
            if self.settings.online:
                await self._command("online on", self.settings.command_timeout_s)
                self._online = True
        except BaseException:
            self._drop_connection()
            raise
        logger.info("connected to the C500C console on %s", self.port)

    async def _handshake(self, connection: _Connection) -> None:
        timeout_s = self.settings.command_timeout_s
        connection.writer.write(proto.CTRL_E)
        await self._discard_until_quiet(connection, timeout_s)
        connection.writer.write(proto.HOST_LINE_END)
        buffer = await self._read_until_prompt(connection, timeout_s, "<CR>", shell_too=True)
        if proto.find_prompt(buffer, proto.SHELL_PROMPT) is not None:
            start = (
                "ash"
                if self.settings.application == "ash"
                else (f"ash {self.settings.application}")
            )
            connection.writer.write(proto.encode_command(start))
            await self._read_until_prompt(connection, timeout_s, start)

    async def _discard_until_quiet(self, connection: _Connection, timeout_s: float) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            try:
                chunk = await asyncio.wait_for(connection.reader.read(4096), HANDSHAKE_QUIET_S)
            except TimeoutError:
                return
            except (OSError, serial.SerialException) as err:
                raise NotConnectedError(DEVICE, f"link lost on {self.port}: {err}") from err
            if not chunk:
                raise NotConnectedError(DEVICE, f"link closed on {self.port}")
            if loop.time() > deadline:
                raise DeviceTimeoutError(DEVICE, "console does not settle after Ctrl-E")

    async def _read_until_prompt(
        self, connection: _Connection, timeout_s: float, command: str, *, shell_too: bool = False
    ) -> bytes:
        buffer = bytearray()

        def complete() -> bool:
            if proto.find_prompt(bytes(buffer), self._prompt) is not None:
                return True
            return shell_too and proto.find_prompt(bytes(buffer), proto.SHELL_PROMPT) is not None

        try:
            async with asyncio.timeout(timeout_s):
                while not complete():
                    chunk = await connection.reader.read(4096)
                    if not chunk:
                        raise _LinkLost
                    buffer += chunk
                    self._bytes_received += len(chunk)
                    if not proto.is_console_text(chunk):  # garbage: say so now, not at timeout
                        raise ProtocolError(
                            DEVICE, f"{command!r}: unexpected bytes in reply: {bytes(buffer)!r}"
                        )
        except TimeoutError as err:
            raise DeviceTimeoutError(
                DEVICE, f"no prompt {timeout_s:g} s after {command!r} (got {bytes(buffer)!r})"
            ) from err
        except (_LinkLost, OSError, serial.SerialException) as err:
            raise NotConnectedError(DEVICE, f"link lost on {self.port} during {command!r}") from err
        return bytes(buffer)

    def _drop_connection(self) -> None:
        connection, self._connection = self._connection, None
        if connection is not None:
            connection.close()

    # --- faults and reconnection ---

    def _hold(self, reason: str) -> None:
        if not self._motion_held:
            logger.warning("robot motion held until resume(): %s", reason)
        self._motion_held = True
        self._last_error = reason

    def _link_fault(self, error: DeviceError) -> None:
        """The link cannot be trusted any more: hold motion, reconnect in the background."""
        self._hold(str(error))
        self._drop_connection()
        self._connected_event.clear()
        self._enter(LinkState.RECONNECTING)
        if self._reconnect_task is None or self._reconnect_task.done():
            self._reconnect_task = asyncio.get_running_loop().create_task(
                self._reconnect(), name="c500c-reconnect"
            )

    async def _reconnect(self) -> None:
        backoff_s = self.first_backoff_s
        while True:
            self._reconnect_attempts += 1
            try:
                async with self._lock:
                    await self._connect()
            except DeviceError as err:
                logger.warning(
                    "reconnection attempt %d failed (%s); next in %.2f s",
                    self._reconnect_attempts,
                    err,
                    backoff_s,
                )
                self._enter(LinkState.RECONNECTING)
                await asyncio.sleep(backoff_s)
                backoff_s = min(
                    backoff_s * RECONNECT_BACKOFF_FACTOR, self.settings.reconnect_max_backoff_s
                )
                continue
            logger.info("reconnected; motion stays held until resume()")
            return

    async def wait_connected(self, timeout_s: float) -> None:
        """Wait until the link is up (after a reconnection); DeviceTimeoutError otherwise."""
        try:
            await asyncio.wait_for(self._connected_event.wait(), timeout_s)
        except TimeoutError as err:
            raise DeviceTimeoutError(DEVICE, f"not reconnected within {timeout_s:g} s") from err

    # --- one command ---

    async def _command(self, command: str, timeout_s: float) -> list[str]:
        """Send one command and return its answer lines; raise on any fault or error line."""
        connection = self._connection
        if connection is None or self._link not in (
            LinkState.CONNECTED,
            LinkState.AWAITING_POINT_OF_CONTROL,
        ):
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        data = proto.encode_command(command)
        try:
            written_at = time.perf_counter()
            connection.writer.write(data)
            self._bytes_sent += len(data)
            raw = await self._read_until_prompt(connection, timeout_s, command)
            self._last_round_trip_s = time.perf_counter() - written_at
            lines = proto.split_reply(raw, command, self._prompt)
        except (DeviceTimeoutError, NotConnectedError, ProtocolError) as err:
            self._link_fault(err)
            raise
        error = proto.first_error(lines)
        if error is not None:
            self._note_device_error(error.code)
            raise DeviceReportedError(DEVICE, error.code, error.text)
        if proto.needs_point_of_control(lines):
            self._enter(LinkState.AWAITING_POINT_OF_CONTROL)
            self._point_of_control = False
            raise PointOfControlError(DEVICE, proto.POINT_OF_CONTROL_MESSAGE)
        return lines

    def _note_device_error(self, code: int | None) -> None:
        if code == 7:
            self._arm_power = False
        elif code == 5:
            self._homed = False
        elif code == 43:
            self._online = False

    async def _read_pose(self) -> Pose:
        lines = await self._command("w2", self.settings.command_timeout_s)
        try:
            return proto.parse_world_pose(lines)
        except ProtocolError as err:
            self._link_fault(err)
            raise

    # --- the Robot protocol ---

    def _require_motion_allowed(self) -> None:
        if self._motion_held:
            raise MotionHeldError(
                DEVICE, f"motion is held after a fault until resume(): {self._last_error}"
            )
        if self._link is not LinkState.CONNECTED:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    async def teach_goal(self) -> Pose:
        async with self._lock:
            await self._command(f"here {GOAL_LOCATION}", self.settings.command_timeout_s)
            self._goal = await self._read_pose()
        logger.info("operational goal taught at %s", self._goal)
        return self._goal

    async def _run_motion(
        self, commands: list[str], requested: Vector3, commanded: Vector3, expected: Vector3
    ) -> MoveResult:
        self._require_motion_allowed()
        sent0, received0 = self._bytes_sent, self._bytes_received
        round_trips_s: list[float] = []
        async with self._lock:
            try:
                for command in commands[:-1]:
                    timeout_s = (
                        self.settings.move_timeout_s
                        if command == "finish"
                        else self.settings.command_timeout_s
                    )
                    await self._command(command, timeout_s)
                    round_trips_s.append(self._last_round_trip_s)
                actual = await self._read_pose()
                round_trips_s.append(self._last_round_trip_s)
            except DeviceError as err:
                self._hold(str(err))
                raise
            self._arm_power, self._homed = True, True
            self._point_of_control = True
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
            actual=actual,
            bytes_sent=self._bytes_sent - sent0,
            bytes_received=self._bytes_received - received0,
            round_trips_s=tuple(round_trips_s),
        )

    @staticmethod
    def _require_finite(values_mm: Vector3) -> None:
        """Last guard before the serial writer (issue 10): the daemon checks every target, but
        a NaN or an infinity would otherwise be printed into a console command as "nan"."""
        if not all(math.isfinite(v) for v in values_mm):
            raise DeviceError(DEVICE, f"refused a non-finite motion target {values_mm}")

    async def move_absolute(self, offset_mm: Vector3) -> MoveResult:
        """Goal + offset (thesis 6.4.4): `set cur = opgoal`, `wshift`, `moves`, `finish`, `w2`."""
        self._require_finite(offset_mm)
        goal = self._goal
        if goal is None:
            raise DeviceError(DEVICE, "no operational goal: call teach_goal() first")
        commands, commanded = proto.absolute_move_commands(
            offset_mm, online=self.settings.online, goal=GOAL_LOCATION, target=TARGET_LOCATION
        )
        expected = (goal.x + commanded[0], goal.y + commanded[1], goal.z + commanded[2])
        return await self._run_motion(commands, offset_mm, commanded, expected)

    async def move_incremental(self, delta_mm: Vector3) -> MoveResult:
        """Relative `wx`/`wy`/`wz` moves (only to reproduce the thesis's comparison)."""
        self._require_finite(delta_mm)
        self._require_motion_allowed()
        commands, commanded = proto.incremental_move_commands(delta_mm)
        async with self._lock:
            start = await self._read_pose()
        expected = (start.x + commanded[0], start.y + commanded[1], start.z + commanded[2])
        return await self._run_motion(commands, delta_mm, commanded, expected)

    async def actual_pose(self) -> Pose:
        async with self._lock:
            return await self._read_pose()

    async def stop(self) -> None:
        """Hold: no further motion until resume(). Moves here are single small `finish`ed
        steps, and no halt command of `ash` is confirmed (C500C.md), so nothing is sent."""
        self._hold("stopped by request")

    async def resume(self) -> None:
        """Allow motion again: the link must be up; the console is checked with a `w2` first."""
        if self._link not in (LinkState.CONNECTED, LinkState.AWAITING_POINT_OF_CONTROL):
            raise NotConnectedError(DEVICE, f"cannot resume while {self._link.value}")
        self._enter(LinkState.CONNECTED)
        await self.actual_pose()
        self._point_of_control = None  # unknown until the next motion command
        self._motion_held = False
        logger.info("robot motion resumed")

    def status(self) -> RobotStatus:
        return RobotStatus(
            link=self._link,
            arm_power=self._arm_power,
            homed=self._homed,
            online=self._online,
            point_of_control=self._point_of_control,
            motion_held=self._motion_held,
            last_error=self._last_error,
            extra={
                "port": self.port,
                "reconnect_attempts": str(self._reconnect_attempts),
                "bytes_sent": str(self._bytes_sent),
                "bytes_received": str(self._bytes_received),
            },
        )

    @property
    def goal(self) -> Pose | None:
        return self._goal
