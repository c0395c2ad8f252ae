"""An emulated CRS C500C console (`ash` shell) on a real pseudo-terminal or a TCP port.

It serves the subset of docs/reference/c500c-console.md the driver uses: echo, prompts, CRLF
replies, arm power / homed / online / point-of-control states, named locations, `new`, `here`,
`set`, `wshift`, `move`, `moves` (error 043 when not online), `wx`/`wy`/`wz` (and their
straight-line `s` forms), `finish`, `w0`/`w2` in the firmware's layout, `online`, `armpower`,
`home`, `speed`, Ctrl-E, the shell `$ ` prompt and `ash [application]`. It asks the firmware's
questions when the host triggers them (`here`/`set` to a variable that does not exist: "-- create
it?"; `ash` without an application: "Application name > "), and a motion command without the point
of control prints the PAUSE/CONTINUE request and blocks until the button is pressed
(:meth:`C500CEmulator.press_pause_continue`, or SIGUSR1 to ``thermocomp emulate``).
The byte-level conventions it follows are those of :mod:`drivers.c500c.protocol`; the
``ASSUMED`` block of :mod:`drivers.c500c.texts` is the one place where unconfirmed parts of the
protocol are written down; the command interpreter (and the emulator's simplifications) is
:mod:`drivers.sim.ash`.

Pacing: every byte costs 10 bit times (8N1 framing: start, 8 data, stop) at the configured baud
rate in both directions, so timings measured against the emulator are those of the real link
(57600 baud: 0.17 ms per byte). Pacing can be turned off for fast tests.

Fault injection (for tests and robustness drills): drop the answer of a command, corrupt one of
its bytes, delay it, stall the console, close the link, or restart the controller (it forgets
its variables). See :func:`parse_faults`.

This module is the serving loop (one conversation per link, the faults applied to its answers,
the controls tests and the bench use); the console's command interpreter is drivers/sim/ash.py
(its state drivers/sim/ash_state.py), the pty / TCP link and the pacing
drivers/sim/emulator_link.py, the configuration and fault specs drivers/sim/emulator_config.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import shutil
import tempfile
from collections.abc import Awaitable, Callable, Coroutine
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

import numpy as np

from config.faults import Fault
from daemon.arm.types import JointSample
from drivers.c500c import protocol as proto
from drivers.sim.ash import Console
from drivers.sim.ash_state import (
    COMMAND_LOG_LINES,
    MOTION_WORDS,
    REACH_MM,
    RESTART_BANNER,
    START_POSE,
    ConsoleCommandError,
    ConsoleState,
    Location,
    as_location,
)
from drivers.sim.emulator_config import (
    CONTROLLER_FAULT_KINDS,
    DEFAULT_DELAY_S,
    DEFAULT_STALL_S,
    FAULT_KINDS,
    EmulatorConfig,
    FaultKind,
    emulator_config,
    parse_faults,
)
from drivers.sim.emulator_link import (
    BITS_PER_CHARACTER,
    Link,
    LinkClosed,
    Pacer,
    PtyLink,
    StreamLink,
)

__all__ = [
    "BITS_PER_CHARACTER",
    "COMMAND_LOG_LINES",
    "CONTROLLER_FAULT_KINDS",
    "FAULT_KINDS",
    "MOTION_WORDS",
    "REACH_MM",
    "RESTART_BANNER",
    "START_POSE",
    "C500CEmulator",
    "Console",
    "ConsoleCommandError",
    "ConsoleState",
    "EmulatorConfig",
    "Fault",
    "FaultKind",
    "Location",
    "as_location",
    "emulator_config",
    "parse_faults",
]

logger = logging.getLogger(__name__)


class C500CEmulator:
    """The emulated controller behind a pseudo-terminal (default) or a TCP port.

    Use it as an async context manager; ``device_path`` is what a host opens: a stable symlink
    to the current pty (it survives a `close` fault) or ``socket://127.0.0.1:<port>`` (pyserial's
    URL for TCP).
    """

    def __init__(
        self,
        config: EmulatorConfig | None = None,
        *,
        transport: Literal["pty", "tcp"] = "pty",
        tcp_port: int = 0,
        link_path: Path | None = None,
    ) -> None:
        self.config = config or EmulatorConfig()
        if self.config.baudrate <= 0:
            raise ValueError("baudrate must be positive")
        seeds = np.random.SeedSequence(self.config.seed).spawn(2)
        self.console = Console(self.config, np.random.default_rng(seeds[0]))
        self._fault_rng = np.random.default_rng(seeds[1])
        self._faults = list(self.config.faults)
        self._pending: list[Fault[FaultKind]] = []
        self.transport = transport
        self._tcp_port = tcp_port
        self._requested_link_path = link_path
        self._temp_dir: str | None = None
        self._link_path: Path | None = None
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._pty: PtyLink | None = None
        self._stalled_until = 0.0
        self.device_path = ""
        self.faults_applied: list[tuple[int, FaultKind]] = []  # (command number, kind)
        # answer gate (tests): hold the answer of a matching command until released
        self._gate_open = asyncio.Event()
        self._gate_open.set()
        self._gate_command: str | None = None
        self.answer_held = asyncio.Event()  # set while an answer waits at the gate

    @property
    def state(self) -> ConsoleState:
        return self.console.state

    # --- control from the test or the bench ---

    def inject(self, kind: FaultKind, seconds: float | None = None) -> None:
        """Apply ``kind`` to the next command line."""
        self._pending.append(Fault(kind, seconds))

    def press_pause_continue(self) -> None:
        """The operator presses PAUSE/CONTINUE: the controller has the point of control, and a
        motion command waiting for it carries on."""
        self.console.press_pause_continue()

    def hold_answers(self, command: str | None = None) -> None:
        """Tests: the answer of the next command line (or of the next one equal to ``command``)
        waits until :meth:`release_answers`; ``answer_held`` is set once one waits. The command
        itself has run when its answer is held."""
        self._gate_command = command
        self._gate_open.clear()
        self.answer_held.clear()

    def release_answers(self) -> None:
        self._gate_open.set()

    def restart_controller(self) -> None:
        """The controller restarts now: it forgets every variable (the taught goal too) and its
        console is at the system shell (docs/reference/c500c-console.md); the link itself stays."""
        logger.info("emulated controller restarts")
        self.console.restart()

    def actual_pose(self) -> Location:
        return self.console.actual_pose(self.console.now())

    def joint_sample(self, t_s: float) -> JointSample:
        """The emulated arm's joint positions, speeds and accelerations at ``t_s`` on the
        emulator's clock (config.clock, else the serving event loop's ``time()``): the motion it
        really performed,
        for the arm bench's motor heat. Only for an emulator with an arm (config.joint_arm)."""
        if self.console.joint_arm is None:
            raise RuntimeError("this emulator has no arm (EmulatorConfig.joint_arm)")
        return self.console.joint_arm.sample(t_s)

    # --- lifecycle ---

    async def __aenter__(self) -> Self:
        if self.transport == "tcp":
            self._server = await asyncio.start_server(
                self._serve_tcp_client, "127.0.0.1", self._tcp_port
            )
            port = self._server.sockets[0].getsockname()[1]
            self.device_path = f"socket://127.0.0.1:{port}"
        else:
            if self._requested_link_path is None:
                self._temp_dir = tempfile.mkdtemp(prefix="c500c-")
                self._link_path = Path(self._temp_dir) / "console"
            else:
                self._link_path = self._requested_link_path
            self._open_pty()
            self.device_path = str(self._link_path)
        logger.info("C500C emulator listening on %s", self.device_path)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
        if self._pty is not None:
            self._pty.close()
            self._pty = None
        if self._link_path is not None:
            with contextlib.suppress(FileNotFoundError):
                self._link_path.unlink()
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None

    def _spawn(self, coroutine: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _open_pty(self) -> None:
        assert self._link_path is not None
        link = PtyLink()
        self._pty = link
        staging = self._link_path.with_name(self._link_path.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            staging.unlink()
        os.symlink(link.slave_path, staging)
        os.replace(staging, self._link_path)  # atomic: a host never sees a missing path
        self._spawn(self._serve_pty(link))

    async def _serve_pty(self, link: PtyLink) -> None:
        try:
            await self._session(link)
        finally:
            link.close()
        if self._pty is link:  # a `close` fault: the cable is plugged back in at once
            self._open_pty()

    async def _serve_tcp_client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        link = StreamLink(reader, writer)
        try:
            await self._session(link)
        finally:
            link.close()
            self._tasks.discard(task)

    # --- one conversation ---

    def _fault_for(self, number: int) -> Fault[FaultKind] | None:
        if self._pending:
            return self._pending.pop(0)
        for fault in self._faults:
            if fault.strikes(number, self._fault_rng):
                return fault
        return None

    async def _session(self, link: Link) -> None:
        pacer_in = Pacer(self.config.baudrate, self.config.paced)
        pacer_out = Pacer(self.config.baudrate, self.config.paced)
        line = bytearray()
        last_was_cr = False
        loop = asyncio.get_running_loop()

        async def send(data: bytes) -> None:
            await pacer_out.take(len(data))
            await link.write(data)

        if self.state.in_shell:
            await send(proto.SHELL_PROMPT)
        try:
            while True:
                chunk = await link.read()
                if not chunk:
                    return
                await pacer_in.take(len(chunk))
                if loop.time() < self._stalled_until:
                    continue  # a stalled controller drops what it is sent
                echo = bytearray()
                for byte in chunk:
                    if byte == proto.CTRL_E[0]:
                        line.clear()
                        self.console.question = None  # emulator choice: Ctrl-E drops a question
                        echo += proto.REPLY_LINE_END + self.console.prompt  # ASSUMED 6
                    elif byte in b"\r\n":
                        if byte == ord("\n") and last_was_cr:
                            last_was_cr = False
                            continue  # the LF of a host's CRLF
                        echo += proto.REPLY_LINE_END
                        await send(bytes(echo))
                        echo.clear()
                        text = line.decode("ascii", errors="replace")
                        line.clear()
                        await self._answer(text, send, link)
                        if loop.time() < self._stalled_until:
                            break
                    elif 0x20 <= byte < 0x7F:
                        line.append(byte)
                        echo.append(byte)
                    last_was_cr = byte == ord("\r")
                if echo:
                    await send(bytes(echo))
        except LinkClosed:
            return

    async def _answer(
        self, text: str, send: Callable[[bytes], Awaitable[None]], link: Link
    ) -> None:
        number = self.state.received + 1
        fault = self._fault_for(number)
        if fault is not None:
            self.faults_applied.append((number, fault.kind))
            logger.info("injecting %s at command %d (%r)", fault.kind, number, text)
        if fault is not None and fault.kind == "close":
            self.state.log_command(text)  # received, never executed
            link.close()
            raise LinkClosed
        if fault is not None and fault.kind == "restart":
            self.state.log_command(text)  # received, never executed
            self.console.restart()
            await send(
                proto.REPLY_LINE_END
                + RESTART_BANNER.encode("ascii")
                + proto.REPLY_LINE_END
                + proto.SHELL_PROMPT
            )
            return
        if fault is not None and fault.kind == "stall":
            self.state.log_command(text)
            seconds = fault.seconds if fault.seconds is not None else DEFAULT_STALL_S
            self._stalled_until = asyncio.get_running_loop().time() + seconds
            return
        lines = await self.console.execute(text)
        if not self._gate_open.is_set() and self._gate_command in (None, text):
            self.answer_held.set()
            await self._gate_open.wait()
            self.answer_held.clear()
        if self.state.awaiting_button:
            # the PAUSE/CONTINUE request goes out now; the rest once the button is pressed
            await send(b"".join(line.encode("ascii") + proto.REPLY_LINE_END for line in lines))
            lines = await self.console.wait_for_button()
        answer = b"".join(line.encode("ascii") + proto.REPLY_LINE_END for line in lines)
        if fault is not None and fault.kind == "drop":
            return
        if fault is not None and fault.kind == "corrupt":
            # A byte the console never sends (outside printable ASCII): detectable by design;
            # a flip that stays printable could only be caught by plausibility checks.
            garbage = int(self._fault_rng.integers(0x80, 0x100))
            if answer:
                position = int(self._fault_rng.integers(0, len(answer)))
                answer = answer[:position] + bytes([garbage]) + answer[position + 1 :]
            else:
                answer = bytes([garbage])
        if fault is not None and fault.kind == "delay":
            await asyncio.sleep(fault.seconds if fault.seconds is not None else DEFAULT_DELAY_S)
        await send(answer + self.console.prompt)
