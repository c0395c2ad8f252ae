"""The emulated controller's RTDE server (port 30004): the subset of the public RTDE guide the
UR driver and ur-rtde's clients use, framed exactly as the guide says
(drivers/ur/rtde_protocol.py).

Per connection: protocol version negotiation (version 2), the controller version, one output
recipe at a chosen frequency (a new setup replaces it while paused), any number of input
recipes, start, pause, data packages both ways, text messages. Unknown variable names are
answered ``NOT_FOUND``; an input variable another connection has set up (or, with a fieldbus
adapter enabled, input registers 0-23) ``IN_USE`` — as the guide describes.

Where the guide is silent (ASSUMED, marked where implemented):
- a setup with any NOT_FOUND or IN_USE variable gets recipe id 0 and is not kept;
- protocol version 1 is refused (the e-Series accepts it; no client here speaks it);
- input data packages are applied whether or not the connection was started (ur-rtde's
  RTDEIOInterface never sends START);
- a setup while started is refused with recipe id 0;
- START with no valid recipe is refused.

Output frequency: the controller's cycle is 500 Hz; a package is sent on each cycle where
``floor(k f / 500)`` increases, so every frequency up to 500 Hz is honoured on average and
500 Hz sends every cycle. A client that does not read loses packages once the socket's send
buffer holds MAX_BUFFERED_BYTES (the guide: "it will skip some output packages").
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from dataclasses import dataclass, field

from drivers.sim.ur.controller import URController
from drivers.ur import rtde_protocol as rtde
from drivers.ur import rtde_variables as variables
from drivers.ur.rtde_protocol import PackageType, Recipe

logger = logging.getLogger(__name__)

RTDE_PORT = 30004
#: How long a closing server waits for its connections' handlers to return (s).
CLOSE_TIMEOUT_S = 2.0
MAX_BUFFERED_BYTES = 256 * 1024
#: Recipe ids a connection hands out (uint8; 0 is "invalid").
MAX_RECIPE_ID = 255
FIELDBUS_REGISTERS = range(0, 24)
SOURCE = "thermocomp emulator"


@dataclass(eq=False)
class RtdeSession:
    """One client connection's recipes and streaming state."""

    writer: asyncio.StreamWriter
    protocol_version: int = 1
    output: Recipe | None = None
    frequency_hz: float = 0.0
    inputs: dict[int, Recipe] = field(default_factory=dict)
    started: bool = False
    next_id: int = 1
    sent: int = 0
    skipped: int = 0
    _phase: int = 0  # floor(k f / 500) of the last package sent

    def due(self, cycle: int) -> bool:
        """Whether controller cycle ``cycle`` sends this session a package (module docstring)."""
        phase = math.floor(cycle * self.frequency_hz / rtde.MAX_FREQUENCY_HZ + 1e-9)
        if phase > self._phase:
            self._phase = phase
            return True
        return False


class RtdeServer:
    """Serves ``controller`` over RTDE on ``host``:``port``; ``tick(cycle, t)`` streams."""

    def __init__(self, controller: URController, host: str, port: int = RTDE_PORT) -> None:
        self.controller = controller
        self.host = host
        self.port = port
        self.sessions: list[RtdeSession] = []
        self._owners: dict[str, RtdeSession] = {}
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        #: True: the network is silent (fault injection): nothing sent, inputs dropped
        self.silent = False
        #: True: the controller's data packages are withheld (a reply held back in flight:
        #: the Robot contract's tests) while its inputs are still read; ``input_withheld`` is
        #: set when an input package arrives meanwhile
        self.withhold = False
        self.input_withheld = asyncio.Event()
        self.inputs_received = 0
        #: data packages sent, and skipped because a client's socket buffer was full
        self.sent_total = 0
        self.skipped_total = 0

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
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
        """Close every client connection (fault injection: a cable pulled)."""
        for session in list(self.sessions):
            session.writer.transport.abort()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        session = RtdeSession(writer)
        self.sessions.append(session)
        decoder = rtde.PackageDecoder()
        try:
            while data := await reader.read(65536):
                for package in decoder.feed(data):
                    self._handle(session, package)
        except rtde.RtdeFormatError as err:
            logger.warning("RTDE client sent garbage (%s): connection closed", err)
        except (ConnectionError, OSError):
            pass
        finally:
            self.sessions.remove(session)
            for name in [n for n, owner in self._owners.items() if owner is session]:
                del self._owners[name]
            writer.transport.abort()
            self._tasks.discard(task)

    def _send(self, session: RtdeSession, data: bytes) -> None:
        if not session.writer.transport.is_closing():
            session.writer.write(data)

    def _handle(self, session: RtdeSession, package: rtde.Package) -> None:
        kind, payload = package.type, package.payload
        if kind == PackageType.DATA_PACKAGE:
            self._input(session, payload)
        elif kind == PackageType.REQUEST_PROTOCOL_VERSION:
            version = rtde.parse_protocol_version_request(payload)
            accepted = version == rtde.PROTOCOL_VERSION  # ASSUMED: version 1 not emulated
            if accepted:
                session.protocol_version = version
            self._send(session, rtde.accepted_reply(PackageType.REQUEST_PROTOCOL_VERSION, accepted))
        elif kind == PackageType.GET_URCONTROL_VERSION:
            self._send(session, rtde.urcontrol_version_reply(self.controller.config.version))
        elif kind == PackageType.CONTROL_PACKAGE_SETUP_OUTPUTS:
            self._setup_outputs(session, payload)
        elif kind == PackageType.CONTROL_PACKAGE_SETUP_INPUTS:
            self._setup_inputs(session, payload)
        elif kind == PackageType.CONTROL_PACKAGE_START:
            ok = session.output is not None or bool(session.inputs)  # ASSUMED
            session.started = session.started or ok
            session._phase = math.floor(
                self.controller.cycles * session.frequency_hz / rtde.MAX_FREQUENCY_HZ + 1e-9
            )
            self._send(session, rtde.accepted_reply(PackageType.CONTROL_PACKAGE_START, ok))
        elif kind == PackageType.CONTROL_PACKAGE_PAUSE:
            session.started = False
            self._send(session, rtde.accepted_reply(PackageType.CONTROL_PACKAGE_PAUSE, True))
        elif kind == PackageType.TEXT_MESSAGE:
            message = rtde.parse_text_message(payload)
            logger.info("RTDE client says (%d): %s", message.level, message.message)
        else:
            self._warn(session, f"unknown package type {kind}")

    def _warn(self, session: RtdeSession, text: str) -> None:
        self._send(session, rtde.text_message(text, SOURCE, rtde.MessageLevel.WARNING))

    def _new_id(self, session: RtdeSession) -> int:
        recipe_id = session.next_id
        session.next_id = min(session.next_id + 1, MAX_RECIPE_ID)
        return recipe_id

    def _setup_outputs(self, session: RtdeSession, payload: bytes) -> None:
        frequency, names = rtde.parse_setup_outputs(payload)
        types = [
            variables.OUTPUTS[n].wire_name if n in variables.OUTPUTS else rtde.NOT_FOUND
            for n in names
        ]
        kind = PackageType.CONTROL_PACKAGE_SETUP_OUTPUTS
        if session.started or not rtde.finite_frequency(frequency) or rtde.NOT_FOUND in types:
            self._send(session, rtde.setup_reply(kind, 0, types))  # ASSUMED: id 0, not kept
            return
        recipe_id = session.output.id if session.output is not None else self._new_id(session)
        session.output = rtde.recipe_of(recipe_id, names, types)
        session.frequency_hz = frequency
        self._send(session, rtde.setup_reply(kind, recipe_id, types))

    def _input_type(self, session: RtdeSession, name: str) -> str:
        if name not in variables.INPUTS:
            return rtde.NOT_FOUND
        owner = self._owners.get(name)
        if owner is not None and owner is not session:
            return rtde.IN_USE
        number = variables.register_number(name)
        if self.controller.config.fieldbus and number in FIELDBUS_REGISTERS and "bit" not in name:
            return rtde.IN_USE
        return variables.INPUTS[name].wire_name

    def _setup_inputs(self, session: RtdeSession, payload: bytes) -> None:
        names = rtde.parse_setup_inputs(payload)
        types = [self._input_type(session, name) for name in names]
        kind = PackageType.CONTROL_PACKAGE_SETUP_INPUTS
        if session.started or rtde.NOT_FOUND in types or rtde.IN_USE in types:
            self._send(session, rtde.setup_reply(kind, 0, types))  # ASSUMED: id 0, not kept
            return
        recipe_id = self._new_id(session)
        session.inputs[recipe_id] = rtde.recipe_of(recipe_id, names, types)
        for name in names:
            self._owners[name] = session
        self._send(session, rtde.setup_reply(kind, recipe_id, types))

    def _input(self, session: RtdeSession, payload: bytes) -> None:
        recipe = session.inputs.get(rtde.data_recipe_id(payload))
        if recipe is None:
            self._warn(session, f"data package of unknown input recipe {payload[0]}")
            return
        values = rtde.parse_data_package(payload, recipe)
        if self.silent:
            return
        self.inputs_received += 1
        if self.withhold:
            self.input_withheld.set()
        for name, value in zip(recipe.names, values, strict=True):
            if name in self.controller.inputs:
                self.controller.write_input(name, value)

    def tick(self, cycle: int, t_s: float) -> None:
        """Controller cycle ``cycle`` at ``t_s``: a data package to every started session
        whose output frequency is due."""
        if self.silent or self.withhold:
            return
        for session in self.sessions:
            if not session.started or session.output is None or not session.due(cycle):
                continue
            transport = session.writer.transport
            if transport.is_closing():
                continue
            if transport.get_write_buffer_size() > MAX_BUFFERED_BYTES:
                session.skipped += 1
                self.skipped_total += 1
                continue
            recipe = session.output
            values = [self.controller.value(name, t_s) for name in recipe.names]
            session.writer.write(rtde.data_package(recipe, values))
            session.sent += 1
            self.sent_total += 1
