"""The C500C console link: the state machine under the robot driver (drivers/c500c/robot.py).

It opens the port, synchronises on a prompt, exchanges commands under one lock, answers or
interrupts the console's questions, waits for the operator when the controller asks for the
point of control, resynchronises after a cut command and reconnects after a link fault. Its
states and their transitions are drivers/c500c/link_states.py.

Synchronisation (connect, reconnect, after a cut command) never waits for the line to go
quiet: it sends Ctrl-E and a probe line the console does not know, and waits, bounded and with
retries, for that line's echo and the prompt after it; whatever came before is discarded.
The motion hold is checked in :meth:`ConsoleLink._exchange`, under the lock, right before a
motion command's bytes are written.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from typing import Self

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import protocol as proto
from drivers.c500c.console import (
    ByteCounters,
    Connection,
    Prompts,
    QuestionAsked,
    ReadOptions,
    Transcript,
    answer_question,
    read_reply,
    synchronise,
)
from drivers.c500c.link_states import LINK_UP, TRANSITIONS, LinkLifecycle
from drivers.errors import (
    ConsoleQuestionError,
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    GoalLostError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)
from drivers.permit import MotionPermit
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S, Reconnector
from drivers.serial_port import open_serial

logger = logging.getLogger(__name__)

DEVICE = proto.DEVICE
#: Name of the taught operational goal and of the per-step target on the controller.
GOAL_LOCATION = "opgoal"
TARGET_LOCATION = "cur"
#: What the console answers when a location variable does not exist [firmware].
VARIABLE_NOT_FOUND = "variable not found."


class ConsoleLink(LinkLifecycle):
    """The console link of one C500C controller (subclassed by the robot driver)."""

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
        self.settings = settings
        #: the one owner of "may the robot move" (drivers/permit.py): every hold goes through it
        self.permit = permit if permit is not None else MotionPermit(DEVICE)
        #: create the per-step target and go online at connect; without it (a check that must
        #: change nothing on the controller) motion is held from the start
        self.prepare = prepare
        self.port = port if port is not None else settings.port
        self.first_backoff_s = first_backoff_s
        self.transcript = transcript
        self._prompt = proto.prompt_pattern(settings.application)
        self._prompts = Prompts(self._prompt)
        self._prompt_or_shell = proto.prompt_or_shell_pattern(settings.application)
        self._connection: Connection | None = None
        self._lock = asyncio.Lock()
        self._link = LinkState.DISCONNECTED
        self.link_history: list[LinkState] = [self._link]  # every state entered, in order
        self._link_changed = asyncio.Event()  # set (and replaced) at every transition
        self._dirty: str | None = None  # why the link must be resynchronised, if it must
        self._stall: str | None = None  # a move's reply that never came, until reconnected
        self._last_error: str | None = None
        self._arm_power: bool | None = None
        self._homed: bool | None = None
        self._online: bool | None = None
        self._point_of_control: bool | None = None
        # the reconnection (drivers/reconnect.py): attempts under the lock, so no command
        # interleaves with a reconnection
        self._reconnector = Reconnector(
            DEVICE,
            self._connect,
            first_backoff_s=lambda: self.first_backoff_s,
            max_backoff_s=lambda: self.settings.reconnect_max_backoff_s,
            lock=self._lock,
            on_failure=lambda _: self._enter(LinkState.RECONNECTING),
            on_success=lambda: logger.info("reconnected; motion stays held until resume()"),
            on_fatal=self._reconnection_failed,
            task_name="c500c-reconnect",
        )
        self._resync_task: asyncio.Task[None] | None = None
        self._resyncs = 0
        self._sync_counter = 0
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

    async def _close(self) -> None:
        await self._reconnector.cancel()
        task, self._resync_task = self._resync_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._drop_connection()
        self._enter(LinkState.DISCONNECTED)
        self._connected_event.clear()

    async def _open_port(self) -> Connection:
        settings = self.settings
        reader, writer = await open_serial(
            DEVICE,
            self.port,
            baudrate=settings.baudrate,
            bytesize=settings.bytesize,
            parity=settings.parity,
            stopbits=settings.stopbits,
            # docs/reference/c500c-console.md: the notes say RTS/CTS "does not seem to work" on the
            # console, the same repository's host service enables it: a setting, off by default
            rtscts=settings.flow_control == "rtscts",
        )
        return Connection(reader, writer, self.transcript, self.counters)

    async def _connect(self) -> None:
        """Open the port, synchronise on a prompt (starting `ash` from the system shell if need
        be), create the per-step target variable, and go online. Called with the lock held."""
        connection = await self._open_port()
        self._connection = connection
        try:
            await self._handshake(connection)
            self._dirty = None
            self._stall = None
            self._enter(LinkState.CONNECTED)
            self._connected_event.set()
            # docs/reference/c500c-console.md "Questions": a new name in `set` may ask "-- create
            # it?"; the target is created once per connection so it never does. The goal is not
            # created here: it exists only once taught, so a controller that lost it says "variable
            # not found."
            if self.prepare:
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
            raw = await self._read_reply(connection, start, timeout_s)
            lines = proto.split_reply(raw, start, self._prompt_or_shell)
            blocked = proto.blocking_message(lines)
            if blocked is not None:
                raise ConsoleQuestionError(DEVICE, f"{start!r}: {blocked}")
            if proto.find_shell_prompt(raw) is not None:
                raise NotConnectedError(
                    DEVICE, f"{start!r} did not start the application: {' / '.join(lines)}"
                )

    async def _synchronise(self, connection: Connection, timeout_s: float) -> bool:
        """Bring the console to a clean prompt (c500c_console.synchronise: Ctrl-E and a probe
        line, bounded). Returns whether the console is at the system shell."""
        raw = await synchronise(
            connection,
            self._prompt_or_shell,
            self._next_probe,
            timeout_s,
            port=self.port,
            application=self.settings.application,
        )
        self._note_prompt(raw)
        return proto.find_shell_prompt(raw[raw.rfind(b"\n") + 1 :]) is not None

    def _next_probe(self) -> str:
        self._sync_counter += 1
        return proto.sync_probe(self._sync_counter)

    def _note_prompt(self, raw: bytes) -> None:
        self._last_prompt = raw[raw.rfind(b"\n") + 1 :].decode("ascii", errors="replace")

    def _drop_connection(self) -> None:
        connection, self._connection = self._connection, None
        if connection is not None:
            connection.close()

    # --- reading ---

    async def _read_reply(self, connection: Connection, command: str, timeout_s: float) -> bytes:
        """``command``'s reply up to its prompt (c500c_console.read_reply). A question ends the
        command with ConsoleQuestionError, answered deliberately when known, else interrupted
        with Ctrl-E and the link resynchronised before the next command: never a hang."""
        options = ReadOptions(
            timeout_s=timeout_s,
            point_of_control_timeout_s=self.settings.point_of_control_timeout_s,
            on_waiting_for_operator=self._waiting_for_operator,
            on_operator_done=self._operator_done,
        )
        try:
            raw, _at_shell = await read_reply(
                connection, self._prompts, command, options, self.port
            )
        except QuestionAsked as asked:
            text = f"{command!r}: the console asked {asked.text.strip()!r}"
            timeout = self.settings.command_timeout_s
            if await answer_question(connection, self._prompts, asked, timeout, self.port):
                answer = asked.question.answer if asked.question is not None else None
                raise ConsoleQuestionError(DEVICE, f"{text}; answered {answer!r}") from None
            self._mark_dirty(text)
            raise ConsoleQuestionError(
                DEVICE, f"{text}, which the driver does not answer"
            ) from None
        self._note_prompt(raw)
        return raw

    def _waiting_for_operator(self) -> None:
        """docs/reference/c500c-console.md "Point of control": the controller waits for
        PAUSE/CONTINUE."""
        self._point_of_control = False
        self._enter(LinkState.AWAITING_POINT_OF_CONTROL)
        logger.warning(
            "the controller waits for PAUSE/CONTINUE (up to %g s)",
            self.settings.point_of_control_timeout_s,
        )

    def _operator_done(self) -> None:
        self._point_of_control = True
        self._enter(LinkState.CONNECTED)

    def _ended_at_shell(self, raw: bytes, command: str) -> None:
        """A reply that ended at the system shell's `$ `: ash exited or the controller
        restarted (a link fault: the reconnection starts ash again)."""
        found = self._prompts.first(raw)
        if found is not None and found[1]:
            raise NotConnectedError(
                DEVICE,
                f"the console answered {command!r} at the system shell `$ `: ash exited or the "
                "controller restarted",
            )

    # --- faults, resynchronisation and reconnection ---

    def _hold(self, reason: str, *, error: bool = True) -> None:
        """Refuse motion from now on until resume() (synchronous: no await in here)."""
        if not self.permit.held:
            # a fault's hold is news; a requested one (every run's end) is routine
            log = logger.warning if error else logger.info
            log("robot motion held until resume(): %s", reason)
        self.permit.hold(reason)
        if error:
            self._last_error = reason

    def _mark_dirty(self, reason: str) -> None:
        """The console may still answer a cut command: resynchronise before the next one."""
        if self._dirty is None:
            logger.warning("C500C link must be resynchronised: %s", reason)
        self._dirty = reason
        if self._link not in LINK_UP:  # closed or reconnecting: the next connect synchronises
            return
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
        """The link cannot be trusted any more: hold motion, reconnect in the background (not
        once the link was closed: a command cut by the close ends here)."""
        self._hold(str(error))
        self._drop_connection()
        self._dirty = None
        self._connected_event.clear()
        if self._link in (LinkState.DISCONNECTED, LinkState.CONNECTING):
            return
        self._enter(LinkState.RECONNECTING)
        self._reconnector.start()

    def _reported_link(self) -> LinkState:
        """The link state status() reports: ``stalled`` after a move's reply timed out, until
        the link is connected again."""
        if self._stall is not None and self._link is not LinkState.CONNECTED:
            return LinkState.STALLED
        return self._link

    def _reconnection_failed(self, error: BaseException) -> None:
        """The reconnection ended on an unexpected error (logged with its traceback): the
        link is failed, motion held, until it is closed and opened again."""
        self._hold(f"the reconnection failed: {error!r}")
        self._enter(LinkState.FAULT)

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
        if connection is None or self._link not in LINK_UP:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        if self._dirty is not None:
            await self._resync(connection)
        motion = any(proto.is_motion_command(command) for command in commands)
        if motion:
            self.permit.require()  # the hold contract: here, under the lock, before the write
        data = b"".join(proto.encode_command(command) for command in commands)
        replies: list[list[str]] = []
        current = commands[0]
        try:
            written_at = time.perf_counter()
            # checked again with the write, atomic against a hold from another thread
            with self.permit.guard(motion):
                connection.write(data)
            for current in commands:
                raw = await self._read_reply(connection, current, timeout_s)
                self._ended_at_shell(raw, current)
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
            if isinstance(err, DeviceTimeoutError) and (motion or current == "finish"):
                self._stall = str(err)  # the link reports "stalled" until it reconnects
            self._link_fault(err)
            raise
        for command, lines in zip(commands, replies, strict=True):
            error = proto.first_error(lines)
            if error is not None:
                self._note_device_error(error.code)
                if error.text == VARIABLE_NOT_FOUND and command.startswith(
                    f"set {TARGET_LOCATION} = "
                ):  # the target is set only from a taught goal: that goal is gone
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
