"""An asyncio RTDE client (the public RTDE guide, protocol version 2; framing in
drivers/ur/rtde_protocol.py).

**Why our own client and not ur-rtde.** ur-rtde (PyPI ``ur-rtde``) is a C++ library with
Python bindings: each interface runs its own threads, its calls block, and they hold the
interpreter lock while they wait (a call from a thread of the daemon stops its event loop: the
project's tests run ur-rtde's clients in a subprocess for that reason). Its RTDEIOInterface
offers five integer and five double registers per range (42-46 in the upper range, with 47
its command register) and no way to choose them, and it cannot stream a recipe of our own.
The protocol is small and publicly specified: an asyncio client keeps every wait cancellable,
one task per link, the hold's bytes written synchronously, and the registers chosen by the
settings. ur-rtde stays what it is best at here: an independent client that checks the
emulator (tests/test_ur_rtde_clients.py).

Use: ``await client.connect()``, ``setup_outputs``, ``setup_inputs``, ``start``; then
``read_data()`` in one task and ``send()`` from any (send writes one whole package without
awaiting, so a cancelled caller never leaves half a package on the wire).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Sequence
from typing import TypeVar

from drivers.errors import DeviceTimeoutError, NotConnectedError, ProtocolError
from drivers.ur import rtde_protocol as rtde
from drivers.ur.rtde_protocol import PackageType, Recipe, TextMessage, Value

logger = logging.getLogger(__name__)

DEVICE = "robot"
READ_CHUNK_BYTES = 65536
#: Text messages kept for status pages and tests.
TEXT_MESSAGES_KEPT = 20

T = TypeVar("T")


class RtdeClient:
    """One RTDE connection (module docstring)."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self.host = host
        self.port = port
        self.timeout_s = timeout_s
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._decoder = rtde.PackageDecoder()
        self._pending: list[rtde.Package] = []
        self.controller_version: tuple[int, int, int, int] | None = None
        self.texts: list[TextMessage] = []
        self.bytes_sent = 0
        self.bytes_received = 0

    @property
    def connected(self) -> bool:
        return self._writer is not None and not self._writer.transport.is_closing()

    async def connect(self) -> None:
        """Open the connection, negotiate protocol version 2, read the controller version."""
        try:
            self._reader, self._writer = await asyncio.wait_for(
                asyncio.open_connection(self.host, self.port), self.timeout_s
            )
        except (OSError, TimeoutError) as err:
            raise NotConnectedError(DEVICE, f"RTDE {self.host}:{self.port}: {err}") from err
        reply = await self.request(
            rtde.request_protocol_version(), PackageType.REQUEST_PROTOCOL_VERSION
        )
        if not rtde.parse_accepted(reply):
            raise ProtocolError(DEVICE, "the controller refused RTDE protocol version 2")
        reply = await self.request(rtde.get_urcontrol_version(), PackageType.GET_URCONTROL_VERSION)
        self.controller_version = self._parse(rtde.parse_urcontrol_version, reply)

    def close(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.transport.abort()

    def send(self, data: bytes) -> None:
        """Write one whole package now (no await: nothing can cut it in half)."""
        writer = self._writer
        if writer is None or writer.transport.is_closing():
            raise NotConnectedError(DEVICE, "RTDE connection closed")
        writer.write(data)
        self.bytes_sent += len(data)

    async def drain(self) -> None:
        if self._writer is not None:
            await self._writer.drain()

    async def _next_package(self) -> rtde.Package:
        while not self._pending:
            reader = self._reader
            if reader is None:
                raise NotConnectedError(DEVICE, "RTDE connection closed")
            try:
                data = await reader.read(READ_CHUNK_BYTES)
            except OSError as err:  # reset by the controller, cable pulled
                raise NotConnectedError(DEVICE, f"RTDE connection lost: {err}") from err
            if not data:
                raise NotConnectedError(DEVICE, "the controller closed the RTDE connection")
            self.bytes_received += len(data)
            try:
                self._pending.extend(self._decoder.feed(data))
            except rtde.RtdeFormatError as err:
                raise ProtocolError(DEVICE, f"RTDE: {err}") from err
        return self._pending.pop(0)

    def _note_text(self, package: rtde.Package) -> None:
        message = self._parse(rtde.parse_text_message, package.payload)
        logger.info("controller says (level %d): %s", message.level, message.message)
        self.texts = [*self.texts[-(TEXT_MESSAGES_KEPT - 1) :], message]

    async def request(self, data: bytes, reply_type: PackageType) -> bytes:
        """Send a control package and wait (at most timeout_s) for its reply's payload; text
        messages on the way are kept, data packages dropped (a reply comes after them)."""
        self.send(data)
        try:
            async with asyncio.timeout(self.timeout_s):
                while True:
                    package = await self._next_package()
                    if package.type == reply_type:
                        return package.payload
                    if package.type == PackageType.TEXT_MESSAGE:
                        self._note_text(package)
        except TimeoutError as err:
            raise DeviceTimeoutError(DEVICE, f"no RTDE reply to {reply_type.name}") from err

    @staticmethod
    def _parse(parse: Callable[[bytes], T], payload: bytes) -> T:
        try:
            return parse(payload)
        except rtde.RtdeFormatError as err:
            raise ProtocolError(DEVICE, f"RTDE: {err}") from err

    async def _setup(self, data: bytes, kind: PackageType, names: Sequence[str]) -> Recipe:
        reply = await self.request(data, kind)
        recipe_id, types = self._parse(rtde.parse_setup_reply, reply)
        recipe = self._parse(lambda _: rtde.recipe_of(recipe_id, names, types), reply)
        if recipe_id == 0:
            raise ProtocolError(DEVICE, f"RTDE {kind.name}: recipe refused")
        return recipe

    async def setup_outputs(self, names: Sequence[str], frequency_hz: float) -> Recipe:
        return await self._setup(
            rtde.setup_outputs(frequency_hz, names),
            PackageType.CONTROL_PACKAGE_SETUP_OUTPUTS,
            names,
        )

    async def setup_inputs(self, names: Sequence[str]) -> Recipe:
        return await self._setup(
            rtde.setup_inputs(names), PackageType.CONTROL_PACKAGE_SETUP_INPUTS, names
        )

    async def start(self) -> None:
        reply = await self.request(rtde.start(), PackageType.CONTROL_PACKAGE_START)
        if not self._parse(rtde.parse_accepted, reply):
            raise ProtocolError(DEVICE, "the controller refused to start RTDE synchronisation")

    async def read_data(self, recipe: Recipe) -> tuple[Value, ...]:
        """The next data package of ``recipe`` (text messages on the way are kept)."""
        while True:
            package = await self._next_package()
            if package.type == PackageType.DATA_PACKAGE:
                return self._parse(lambda p: rtde.parse_data_package(p, recipe), package.payload)
            if package.type == PackageType.TEXT_MESSAGE:
                self._note_text(package)

    async def aclose(self) -> None:
        """Pause synchronisation when the link is up, let what was written go out (a hold
        flag written just before must reach the controller), then close."""
        writer = self._writer
        if writer is not None and self.connected:
            with contextlib.suppress(OSError, NotConnectedError, TimeoutError):
                self.send(rtde.pause())
                async with asyncio.timeout(self.timeout_s):
                    writer.close()
                    await writer.wait_closed()
        self.close()
