"""The CRS C500C controller's `ash` console over RS-232 (pyserial-asyncio): the robot driver.

Every exchange is one command line, its echo, its answer lines and a prompt
(drivers/c500c_protocol.py). Each command has a timeout; a garbled or missing reply is an error,
never a guess. Link states (drivers.base.LinkState):

    DISCONNECTED --__aenter__--> CONNECTING --synchronised--> CONNECTED
    CONNECTED --a command cut (cancelled)--> RESYNCHRONISING --probe answered--> CONNECTED
    CONNECTED --link fault--> RECONNECTING --attempt ok--> CONNECTED (motion held)
    RECONNECTING --attempt fails--> wait backoff, try again (first 0.5 s, x2, capped)
    CONNECTED --"Press the PAUSE/CONTINUE..."--> AWAITING_POINT_OF_CONTROL --button--> CONNECTED
    any --__aexit__--> DISCONNECTED

Synchronisation (connect, reconnect, after a cut command) never waits for the line to go
quiet: it sends Ctrl-E and a probe line the console does not know, and waits, bounded and with
retries, for that line's echo and the prompt after it; whatever came before is discarded.

**The hold.** :meth:`C500CRobot.stop` holds motion from the instant it is called: every motion
command (`move`, `moves`, `wx`..., see ``c500c_protocol.MOTION_COMMANDS``) checks the hold under
the driver's lock immediately before its bytes are written, so a move queued behind another
command (a read-back, a teach, the reconnection) is refused with MotionHeldError. Only
:meth:`C500CRobot.resume` releases a hold. What a hold cannot do on this console: stop a motion
already written. `ash` has no known command that halts a motion in progress (C500C.md), so the
move under way (one small compensation step, `finish`ed before the next) runs to its end; the
controller-side fast-path program can halt (RAPL-3 `halt()`), and the hardware E-stop remains
the operator's way to stop the arm now. Likewise a motion command waiting for the point of
control moves the arm when the operator presses PAUSE/CONTINUE, even after the driver gave up.

After a link fault the driver reconnects in the background, but sends no motion until the caller
explicitly resumes (a robot must never move on its own after something went wrong).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, Self

import serial
import serial_asyncio

from config.settings import RobotSettings
from drivers import c500c_protocol as proto
from drivers.base import LinkState, MoveResult, Pose, RobotStatus, Vector3
from drivers.c500c_console import ByteCounters, Connection, LinkLost, Transcript
from drivers.errors import (
    ConsoleQuestionError,
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    GoalLostError,
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
#: Probe lines tried before synchronisation gives up (each waits robot.command_timeout_s).
SYNC_ATTEMPTS = 3
#: An unrecognised question (a line ending in "? " or ": " without a line end) is taken as one
#: when nothing more arrives for this long (s); a known question is recognised at once.
QUESTION_SETTLE_S = 0.5
#: A read-back farther than this from the commanded goal is not believed (mm): ten times the
#: A465's +-0.05 mm repeatability (thesis 3.2.1), so only a garbled table can exceed it.
READBACK_TOLERANCE_MM = 0.5
#: Name of the taught operational goal and of the per-step target on the controller.
GOAL_LOCATION = "opgoal"
TARGET_LOCATION = "cur"
#: What the console answers when a location variable does not exist [firmware].
VARIABLE_NOT_FOUND = "variable not found."


#: The link's state machine: every allowed transition (drivers.base.LinkState). FAULT is not
#: used here: a broken link is RECONNECTING, a device-reported fault holds motion instead.
TRANSITIONS: dict[LinkState, frozenset[LinkState]] = {
    LinkState.DISCONNECTED: frozenset({LinkState.CONNECTING}),
    LinkState.CONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
    LinkState.CONNECTED: frozenset(
        {
            LinkState.AWAITING_POINT_OF_CONTROL,
            LinkState.RESYNCHRONISING,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.AWAITING_POINT_OF_CONTROL: frozenset(
        {
            LinkState.CONNECTED,
            LinkState.RESYNCHRONISING,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.RESYNCHRONISING: frozenset(
        {
            LinkState.CONNECTED,
            LinkState.AWAITING_POINT_OF_CONTROL,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.RECONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
}
#: States in which commands can be exchanged.
_LINK_UP = frozenset(
    {LinkState.CONNECTED, LinkState.AWAITING_POINT_OF_CONTROL, LinkState.RESYNCHRONISING}
)

# Kept importable under its former name for tests that script a connection.
_Connection = Connection


async def _done() -> None:
    """An awaitable that has nothing left to do."""


class C500CRobot:
    """The robot as the daemon sees it (drivers.base.Robot) on a C500C console."""

    def __init__(
        self,
        settings: RobotSettings,
        *,
        port: str | None = None,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
        transcript: Transcript | None = None,
    ) -> None:
        self.settings = settings
        self.port = port if port is not None else settings.port
        self.first_backoff_s = first_backoff_s
        self.transcript = transcript
        self._prompt = proto.prompt_pattern(settings.application)
        self._prompt_or_shell = proto.prompt_or_shell_pattern(settings.application)
        self._connection: Connection | None = None
        self._lock = asyncio.Lock()
        self._link = LinkState.DISCONNECTED
        self.link_history: list[LinkState] = [self._link]  # every state entered, in order
        self._link_changed = asyncio.Event()  # set (and replaced) at every transition
        self._motion_held = False
        self._hold_reason: str | None = None
        self._dirty: str | None = None  # why the link must be resynchronised, if it must
        self._last_error: str | None = None
        self._goal: Pose | None = None
        self._arm_power: bool | None = None
        self._homed: bool | None = None
        self._online: bool | None = None
        self._point_of_control: bool | None = None
        self._reconnect_task: asyncio.Task[None] | None = None
        self._resync_task: asyncio.Task[None] | None = None
        self._reconnect_attempts = 0
        self._resyncs = 0
        self._sync_counter = 0
        self._moves = 0  # moves since the goal was taught (robot.readback_every counts them)
        self._last_prompt = ""
        self._connected_event = asyncio.Event()
        self.counters = ByteCounters()
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
        changed, self._link_changed = self._link_changed, asyncio.Event()
        changed.set()

    async def __aenter__(self) -> Self:
        self._enter(LinkState.CONNECTING)
        try:
            async with self._lock:
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
        for name in ("_reconnect_task", "_resync_task"):
            task: asyncio.Task[None] | None = getattr(self, name)
            setattr(self, name, None)
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._drop_connection()
        self._enter(LinkState.DISCONNECTED)
        self._connected_event.clear()

    async def _open_port(self) -> Connection:
        settings = self.settings

        def open_blocking() -> Any:
            # Opening a port can block (USB adapters, termios): never on the event loop.
            return serial.serial_for_url(
                self.port,
                baudrate=settings.baudrate,
                bytesize=settings.bytesize,
                parity=settings.parity,
                stopbits=settings.stopbits,
                # C500C.md: the notes say RTS/CTS "does not seem to work" on the console, the
                # same repository's host service enables it: a setting, off by default
                rtscts=settings.flow_control == "rtscts",
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
        writer = asyncio.StreamWriter(transport, protocol, reader, loop)
        return Connection(reader, writer, self.transcript, self.counters)

    async def _connect(self) -> None:
        """Open the port, synchronise on a prompt (starting `ash` from the system shell if need
        be), create the per-step target variable, and go online. Called with the lock held."""
        connection = await self._open_port()
        self._connection = connection
        try:
            await self._handshake(connection)
            self._dirty = None
            self._enter(LinkState.CONNECTED)
            self._connected_event.set()
            # C500C.md "Questions": a new name in `set` may ask "-- create it?"; the target is
            # created once per connection so it never does. The goal is not created here: it
            # exists only once taught, so a controller that lost it says "variable not found."
            await self._create_variable(TARGET_LOCATION)
            if self.settings.online:
                await self._command("online on", self.settings.command_timeout_s)
                self._online = True
        except BaseException:
            self._drop_connection()
            self._connected_event.clear()
            raise
        logger.info("connected to the C500C console on %s", self.port)

    async def _handshake(self, connection: Connection) -> None:
        timeout_s = self.settings.command_timeout_s
        at_shell = await self._synchronise(connection, timeout_s)
        if at_shell:
            # `ash` without an argument asks "Application name > " [firmware]: always name it
            start = f"ash {self.settings.application}"
            connection.write(proto.encode_command(start))
            raw = await self._read_reply(connection, start, timeout_s, shell_ok=True)
            lines = proto.split_reply(raw, start, self._prompt_or_shell)
            blocked = proto.blocking_message(lines)
            if blocked is not None:
                raise ConsoleQuestionError(DEVICE, f"{start!r}: {blocked}")
            if proto.find_shell_prompt(raw) is not None:
                raise NotConnectedError(
                    DEVICE, f"{start!r} did not start the application: {' / '.join(lines)}"
                )

    async def _synchronise(self, connection: Connection, timeout_s: float) -> bool:
        """Bring the console to a clean prompt: Ctrl-E and a probe line; the reply is complete
        at the prompt after the probe's echo (ASSUMED 6). Bounded: SYNC_ATTEMPTS probes, each
        waiting ``timeout_s``. Returns whether the console is at the system shell."""
        prompts = self._prompt_or_shell
        last: DeviceError | None = None
        for _attempt in range(SYNC_ATTEMPTS):
            self._sync_counter += 1
            probe = proto.sync_probe(self._sync_counter)
            connection.write(proto.CTRL_E + proto.encode_command(probe))
            try:
                end = await self._read_until(
                    connection,
                    functools.partial(proto.find_probe_answer, probe=probe, prompt=prompts),
                    timeout_s,
                    f"synchronisation probe {probe!r}",
                )
            except DeviceTimeoutError as err:
                last = err
                continue
            raw = connection.take(end)
            self._note_prompt(raw)
            return proto.find_shell_prompt(raw[raw.rfind(b"\n") + 1 :]) is not None
        raise DeviceTimeoutError(
            DEVICE, f"console not synchronised after {SYNC_ATTEMPTS} probe lines: {last}"
        )

    def _note_prompt(self, raw: bytes) -> None:
        self._last_prompt = raw[raw.rfind(b"\n") + 1 :].decode("ascii", errors="replace")

    def _drop_connection(self) -> None:
        connection, self._connection = self._connection, None
        if connection is not None:
            connection.close()

    # --- reading ---

    async def _read_until(
        self,
        connection: Connection,
        complete: Callable[[bytes], int | None],
        timeout_s: float,
        what: str,
    ) -> int:
        """Read until ``complete(pending)`` gives the end index of a reply."""
        try:
            async with asyncio.timeout(timeout_s):
                while (end := complete(bytes(connection.pending))) is None:
                    chunk = await connection.read_more()
                    if not proto.is_console_text(chunk):  # garbage: say so now, not at timeout
                        raise ProtocolError(
                            DEVICE, f"{what}: unexpected bytes: {bytes(connection.pending)!r}"
                        )
        except TimeoutError as err:
            raise DeviceTimeoutError(
                DEVICE,
                f"no answer {timeout_s:g} s after {what} (got {bytes(connection.pending)!r})",
            ) from err
        except LinkLost as err:
            raise NotConnectedError(DEVICE, f"link lost on {self.port} during {what}") from err
        return end

    def _first_prompt(self, buffer: bytes) -> tuple[int, bool] | None:
        """The end of the first reply in ``buffer`` and whether the system shell's prompt
        ended it (ash exited or the controller restarted)."""
        ash = proto.find_prompt(buffer, self._prompt)
        shell = proto.find_shell_prompt(buffer)
        if shell is not None and (ash is None or shell < ash):
            return shell, True
        if ash is not None:
            return ash, False
        return None

    async def _read_reply(
        self, connection: Connection, command: str, timeout_s: float, *, shell_ok: bool = False
    ) -> bytes:
        """The bytes of ``command``'s reply up to its prompt (the rest stays pending).

        While reading: the PAUSE/CONTINUE request switches the state to waiting for the
        operator and the deadline to robot.point_of_control_timeout_s (C500C.md "Point of
        control"); a question ends the command with ConsoleQuestionError (answered
        deliberately when known, Ctrl-E otherwise), never a hang."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        awaiting_operator = False
        try:
            while True:
                buffer = bytes(connection.pending)
                found = self._first_prompt(buffer)
                if not awaiting_operator and proto.needs_point_of_control(
                    buffer[: None if found is None else found[0]]
                ):
                    awaiting_operator = True
                    self._point_of_control = False
                    self._enter(LinkState.AWAITING_POINT_OF_CONTROL)
                    logger.warning(
                        "the controller waits for PAUSE/CONTINUE (up to %g s)",
                        self.settings.point_of_control_timeout_s,
                    )
                    deadline = loop.time() + self.settings.point_of_control_timeout_s
                if found is not None:
                    end, at_shell = found
                    raw = connection.take(end)
                    self._note_prompt(raw)
                    if awaiting_operator:
                        self._point_of_control = True
                        self._enter(LinkState.CONNECTED)
                    if at_shell and not shell_ok:
                        raise NotConnectedError(
                            DEVICE,
                            f"the console answered {command!r} at the system shell `$ `: "
                            "ash exited or the controller restarted",
                        )
                    return raw
                question = proto.find_question(buffer)
                if question is not None:
                    await self._refuse_question(connection, command, question.text, question)
                remaining = deadline - loop.time()
                if remaining <= 0:
                    if awaiting_operator:
                        raise PointOfControlError(
                            DEVICE,
                            f"nobody pressed PAUSE/CONTINUE within "
                            f"{self.settings.point_of_control_timeout_s:g} s after {command!r}",
                        )
                    raise DeviceTimeoutError(
                        DEVICE, f"no prompt {timeout_s:g} s after {command!r} (got {buffer!r})"
                    )
                maybe_question = proto.may_be_question(buffer)
                wait_s = min(remaining, QUESTION_SETTLE_S) if maybe_question else remaining
                try:
                    chunk = await asyncio.wait_for(connection.read_more(), wait_s)
                except TimeoutError:
                    if maybe_question and bytes(connection.pending) == buffer:
                        tail = proto.pending_line(buffer)
                        await self._refuse_question(connection, command, tail, None)
                    continue
                if not proto.is_console_text(chunk):  # garbage: say so now, not at timeout
                    raise ProtocolError(
                        DEVICE,
                        f"{command!r}: unexpected bytes in reply: {bytes(connection.pending)!r}",
                    )
        except LinkLost as err:
            raise NotConnectedError(DEVICE, f"link lost on {self.port} during {command!r}") from err

    async def _refuse_question(
        self,
        connection: Connection,
        command: str,
        text: str,
        question: proto.Question | None,
    ) -> None:
        """End a command the console turned into a question (C500C.md "Questions"): a known
        question gets its deliberate answer and the prompt is awaited; anything else gets
        Ctrl-E and the link is resynchronised before the next command."""
        connection.take(len(connection.pending))
        asked = f"{command!r}: the console asked {text.strip()!r}"
        if question is not None and question.answer is not None:
            connection.write(proto.encode_command(question.answer))
            try:
                end = await self._read_until(
                    connection,
                    self._end_of_answer,
                    self.settings.command_timeout_s,
                    f"the answer {question.answer!r}",
                )
            except DeviceTimeoutError:
                pass  # no prompt after the answer: resynchronise below
            else:
                answered = connection.take(end)
                if proto.find_question(answered) is None:
                    raise ConsoleQuestionError(DEVICE, f"{asked}; answered {question.answer!r}")
        connection.write(proto.CTRL_E)
        self._mark_dirty(asked)
        raise ConsoleQuestionError(DEVICE, f"{asked}, which the driver does not answer")

    def _end_of_answer(self, buffer: bytes) -> int | None:
        found = self._first_prompt(buffer)
        if found is not None:
            return found[0]
        return len(buffer) if proto.find_question(buffer) is not None else None

    # --- faults, resynchronisation and reconnection ---

    def _hold(self, reason: str, *, error: bool = True) -> None:
        """Refuse motion from now on until resume() (synchronous: no await in here)."""
        if not self._motion_held:
            logger.warning("robot motion held until resume(): %s", reason)
            self._hold_reason = reason
        self._motion_held = True
        if error:
            self._last_error = reason

    def _mark_dirty(self, reason: str) -> None:
        """The console may still answer a cut command: resynchronise before the next one."""
        if self._dirty is None:
            logger.warning("C500C link must be resynchronised: %s", reason)
        self._dirty = reason
        if self._link in (LinkState.CONNECTED, LinkState.RESYNCHRONISING):
            self._enter(LinkState.RESYNCHRONISING)
        if self._resync_task is None or self._resync_task.done():
            self._resync_task = asyncio.get_running_loop().create_task(
                self._resync_in_background(), name="c500c-resync"
            )

    async def _resync_in_background(self) -> None:
        """Resynchronise soon after a cut command, so the status recovers on its own."""
        with contextlib.suppress(DeviceError):
            async with self._lock:
                connection = self._connection
                if connection is not None and self._dirty is not None:
                    await self._resync(connection)

    async def _resync(self, connection: Connection) -> None:
        """Ctrl-E and a probe until a clean prompt (called with the lock held); a console that
        does not come back is a link fault (reconnection)."""
        if self._link is not LinkState.AWAITING_POINT_OF_CONTROL:
            self._enter(LinkState.RESYNCHRONISING)
        try:
            at_shell = await self._synchronise(connection, self.settings.command_timeout_s)
            if at_shell:
                raise NotConnectedError(
                    DEVICE, "the console is at the system shell: ash exited or it restarted"
                )
        except (DeviceTimeoutError, NotConnectedError, ProtocolError) as err:
            self._link_fault(err)
            raise
        self._resyncs += 1
        self._dirty = None
        self._enter(LinkState.CONNECTED)
        logger.info("C500C link resynchronised")

    def _link_fault(self, error: DeviceError) -> None:
        """The link cannot be trusted any more: hold motion, reconnect in the background."""
        self._hold(str(error))
        self._drop_connection()
        self._dirty = None
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

    async def wait_link(self, state: LinkState, timeout_s: float) -> None:
        """Wait until the link is in ``state``; DeviceTimeoutError otherwise."""
        try:
            async with asyncio.timeout(timeout_s):
                while self._link is not state:
                    await self._link_changed.wait()
        except TimeoutError as err:
            raise DeviceTimeoutError(
                DEVICE, f"link not {state.value} within {timeout_s:g} s ({self._link.value})"
            ) from err

    async def wait_connected(self, timeout_s: float) -> None:
        """Wait until the link is up (after a reconnection); DeviceTimeoutError otherwise."""
        try:
            await asyncio.wait_for(self._connected_event.wait(), timeout_s)
        except TimeoutError as err:
            raise DeviceTimeoutError(DEVICE, f"not reconnected within {timeout_s:g} s") from err

    # --- commands ---

    async def _command(self, command: str, timeout_s: float) -> list[str]:
        """Send one command and return its answer lines; raise on any fault or error line."""
        (lines,) = await self._exchange((command,), timeout_s)
        return lines

    async def _exchange(self, commands: proto.Write, timeout_s: float) -> list[list[str]]:
        """Write ``commands`` at once and read each one's reply (called with the lock held).

        The hold is checked here, after any resynchronisation and right before the write, which
        is synchronous: once stop() has run, no motion command's bytes can go out. A command
        cut mid-exchange (its task cancelled) leaves the link dirty; a cut motion command also
        holds motion."""
        assert self._lock.locked(), "console commands are exchanged under the driver's lock"
        connection = self._connection
        if connection is None or self._link not in _LINK_UP:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        if self._dirty is not None:
            await self._resync(connection)
        motion = any(proto.is_motion_command(command) for command in commands)
        if motion and self._motion_held:
            raise MotionHeldError(DEVICE, f"motion is held until resume(): {self._hold_reason}")
        data = b"".join(proto.encode_command(command) for command in commands)
        replies: list[list[str]] = []
        current = commands[0]
        try:
            written_at = time.perf_counter()
            connection.write(data)
            for current in commands:
                raw = await self._read_reply(connection, current, timeout_s)
                replies.append(proto.split_reply(raw, current, self._prompt))
            self._last_round_trip_s = time.perf_counter() - written_at
        except asyncio.CancelledError:
            if motion or current == "finish":
                self._hold(f"{current!r} was cut before its answer")
            self._mark_dirty(f"{current!r} was cancelled before its answer")
            raise
        except PointOfControlError as err:
            self._hold(str(err))
            self._mark_dirty(str(err))
            raise
        except (DeviceTimeoutError, NotConnectedError, ProtocolError) as err:
            self._link_fault(err)
            raise
        for command, lines in zip(commands, replies, strict=True):
            error = proto.first_error(lines)
            if error is not None:
                self._note_device_error(error.code)
                if error.text == VARIABLE_NOT_FOUND and command.endswith(f"= {GOAL_LOCATION}"):
                    raise GoalLostError(DEVICE, f"{command!r} answered {error.text!r}")
                raise DeviceReportedError(DEVICE, error.code, error.text)
            blocked = proto.blocking_message(lines)
            if blocked is not None:
                raise ConsoleQuestionError(DEVICE, f"{command!r}: {blocked}")
        return replies

    def _note_device_error(self, code: int | None) -> None:
        if code == 7:
            self._arm_power = False
        elif code == 5:
            self._homed = False
        elif code == proto.ONLINE_ERROR_CODE:
            self._online = False

    async def _create_variable(self, name: str) -> None:
        """`new <name>` (ASSUMED 7): a name that exists already answers an error; both do."""
        with contextlib.suppress(DeviceReportedError):
            await self._command(f"new {name}", self.settings.command_timeout_s)

    async def _read_pose(self) -> Pose:
        lines = await self._command("w2", self.settings.command_timeout_s)
        try:
            return proto.parse_world_pose(lines)
        except ProtocolError as err:
            self._link_fault(err)
            raise

    # --- the Robot protocol ---

    def _require_motion_allowed(self) -> None:
        """A quick refusal before waiting for the lock; the binding check is in _exchange."""
        if self._motion_held:
            raise MotionHeldError(DEVICE, f"motion is held until resume(): {self._hold_reason}")
        if self._link not in (LinkState.CONNECTED, LinkState.RESYNCHRONISING):
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    async def teach_goal(self) -> Pose:
        """`new opgoal`, `here opgoal`, then `w2`: moves nothing, so it is allowed while held."""
        async with self._lock:
            await self._create_variable(GOAL_LOCATION)
            await self._command(f"here {GOAL_LOCATION}", self.settings.command_timeout_s)
            self._goal = await self._read_pose()
            self._moves = 0
        logger.info("operational goal taught at %s", self._goal)
        return self._goal

    def _readback_due(self) -> bool:
        return self._moves % self.settings.readback_every == 0

    async def _run_motion(
        self,
        writes: list[proto.Write],
        requested: Vector3,
        commanded: Vector3,
        expected: Vector3 | None,
    ) -> MoveResult:
        """The writes of one move (the last is the `w2` read-back when ``expected`` is given);
        called with the lock held."""
        sent0, received0 = self.counters.sent, self.counters.received
        round_trips_s: list[float] = []
        actual: Pose | None = None
        try:
            for write in writes:
                timeout_s = (
                    self.settings.move_timeout_s
                    if "finish" in write
                    else self.settings.command_timeout_s
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
        )

    @staticmethod
    def _require_finite(values_mm: Vector3) -> None:
        """Last guard before the serial writer (issue 10): the daemon checks every target, but
        a NaN or an infinity would otherwise be printed into a console command as "nan"."""
        if not all(math.isfinite(v) for v in values_mm):
            raise DeviceError(DEVICE, f"refused a non-finite motion target {values_mm}")

    async def move_absolute(self, offset_mm: Vector3) -> MoveResult:
        """Goal + offset (thesis 6.4.4): `set cur = opgoal` and `wshift` in one write, `moves`,
        `finish`, and the `w2` read-back every robot.readback_every-th move."""
        self._require_finite(offset_mm)
        goal = self._goal
        if goal is None:
            raise DeviceError(DEVICE, "no operational goal: call teach_goal() first")
        self._require_motion_allowed()
        async with self._lock:
            # again under the lock: a hold that came while this waited sends nothing of the move
            self._require_motion_allowed()
            readback = self._readback_due()
            writes, commanded = proto.absolute_move_commands(
                offset_mm,
                online=self.settings.online,
                goal=GOAL_LOCATION,
                target=TARGET_LOCATION,
                readback=readback,
            )
            expected = (goal.x + commanded[0], goal.y + commanded[1], goal.z + commanded[2])
            return await self._run_motion(writes, offset_mm, commanded, expected)

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
            return await self._run_motion(writes, delta_mm, commanded, expected)

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

    async def resume(self) -> None:
        """Allow motion again. The link must be up; the console is checked first: the taught
        goal must still exist on the controller (`set cur = opgoal`), else GoalLostError and the
        hold stays; then a `w2`.

        A lost goal is not re-created from the recorded pose: the console's read-out has only
        0.001 mm and no arm configuration (stance) for it, and after a restart the calibration
        it was taught in may be gone, so a goal rebuilt that way could differ from the taught
        one without anything showing it (C500C.md); teaching it again is the operator's call."""
        async with self._lock:
            if self._link not in _LINK_UP:
                raise NotConnectedError(DEVICE, f"cannot resume while {self._link.value}")
            if self._goal is not None:
                try:
                    await self._command(
                        f"set {TARGET_LOCATION} = {GOAL_LOCATION}", self.settings.command_timeout_s
                    )
                except GoalLostError as err:
                    self._last_error = str(err)
                    raise
            await self._read_pose()
            if self._link is LinkState.AWAITING_POINT_OF_CONTROL:
                self._enter(LinkState.CONNECTED)
            self._point_of_control = None  # unknown until the next motion command
            self._motion_held = False
            self._hold_reason = None
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
            hold_reason=self._hold_reason if self._motion_held else None,
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
        return self._goal
