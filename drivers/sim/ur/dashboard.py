"""The emulated controller's Dashboard Server (port 29999): a line protocol, one command per
line, one answer line each, after a welcome line. The answers are those of UR's Dashboard
Server manual for e-Series (PolyScope 5); ur-rtde's DashboardClient checks some of them word
for word ("Starting program", "Pausing program").

Subset: play, pause, stop, programState, running, robotmode, safetystatus, safetymode,
PolyscopeVersion, get loaded program, unlock protective stop, close safety popup,
isInRemoteControl, quit. Anything else: ``could not understand: '<line>'``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

from drivers.sim.ur.controller import URController
from drivers.ur.modes import PROGRAM_STATE_WORDS, RuntimeState

logger = logging.getLogger(__name__)

DASHBOARD_PORT = 29999
CLOSE_TIMEOUT_S = 2.0  # as the RTDE server's
WELCOME = "Connected: Universal Robots Dashboard Server"
#: The longest command line read (bytes): longer is garbage and closes the connection.
MAX_LINE_BYTES = 4096
#: "unlock protective stop" when there is none to unlock (ASSUMED wording).
UNLOCK_REFUSED = "Failed to execute: unlock protective stop"


class DashboardServer:
    def __init__(
        self,
        controller: URController,
        clock: Callable[[], float],
        host: str,
        port: int = DASHBOARD_PORT,
    ) -> None:
        self.controller = controller
        self.clock = clock
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self.commands: list[str] = []  # every command received, for tests

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._serve, self.host, self.port, limit=MAX_LINE_BYTES
        )
        sockets = self._server.sockets
        if sockets:
            self.port = int(sockets[0].getsockname()[1])

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        self.drop_connections()  # each handler sees its connection end and returns
        tasks = list(self._tasks)
        if tasks:
            _, pending = await asyncio.wait(tasks, timeout=CLOSE_TIMEOUT_S)
            for task in pending:
                task.cancel()
            for task in pending:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    def drop_connections(self) -> None:
        for writer in list(self._writers):
            writer.transport.abort()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.add(writer)
        try:
            writer.write(f"{WELCOME}\n".encode())
            while line := await reader.readline():
                command = line.decode("ascii", "replace").strip()
                self.commands.append(command)
                answer = self.answer(command)
                writer.write(f"{answer}\n".encode())
                await writer.drain()
                if command == "quit":
                    break
        except (ConnectionError, OSError, ValueError, asyncio.LimitOverrunError):
            pass
        finally:
            self._writers.discard(writer)
            writer.transport.abort()
            self._tasks.discard(task)

    def answer(self, command: str) -> str:
        """The Dashboard Server's answer to one command line."""
        c, now = self.controller, self.clock()
        lowered = command.lower()
        if lowered == "play":
            return "Starting program" if c.play(now) else "Failed to execute: play"
        if lowered == "pause":
            return "Pausing program" if c.pause(now) else "Failed to execute: pause"
        if lowered == "stop":
            return "Stopped" if c.stop(now) else "Failed to execute: stop"
        if lowered == "programstate":
            return f"{PROGRAM_STATE_WORDS[c.runtime_state]} {c.config.program_name}"
        if lowered == "running":
            return f"Program running: {str(c.runtime_state is RuntimeState.PLAYING).lower()}"
        if lowered == "robotmode":
            return f"Robotmode: {c.robot_mode.name}"
        if lowered == "safetystatus":
            return f"Safetystatus: {c.safety_mode.name}"
        if lowered == "safetymode":
            return f"Safetymode: {c.safety_mode.name}"
        if lowered == "polyscopeversion":
            return "URSoftware {}.{}.{}.{} (emulated)".format(*c.config.version)
        if lowered == "get loaded program":
            return f"Loaded program: /programs/{c.config.program_name}"
        if lowered == "unlock protective stop":
            if c.unlock_protective_stop():
                return "Protective stop releasing"
            return UNLOCK_REFUSED
        if lowered == "close safety popup":
            return "closing safety popup"
        if lowered == "isinremotecontrol":
            return "true"
        if lowered == "quit":
            return "Disconnected"
        return f"could not understand: '{command}'"
