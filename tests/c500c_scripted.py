"""The C500C driver against a scripted console (pymeasure ``expected_protocol`` style).

A scripted console checks every byte the driver writes against the recorded exchange, answers
with the recorded bytes, and :meth:`ScriptedRobot.assert_all_used` fails unless every exchange
was used. Scripts come from the tests or from a transcript (``thermocomp robot check
--transcript``).
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any

from config.settings import RobotSettings
from drivers.c500c import protocol as console_proto
from drivers.c500c.console import Connection
from drivers.c500c.robot import C500CRobot

Script = Sequence[tuple[bytes, bytes]]
PROMPT = b"ash> "


def ok_exchange(command: bytes) -> tuple[bytes, bytes]:
    """A command the console echoes and answers with its prompt alone."""
    return (command + b"\r", command + b"\r\n" + PROMPT)


def probe_exchange() -> tuple[bytes, bytes]:
    """The driver's first synchronisation probe and the console's answer to it."""
    line = b"tcsync1"
    return (b"\x05" + line + b"\r", line + b"\r\nerror: Unrecognized command.\r\n" + PROMPT)


def w2_exchange(pose: tuple[float, ...]) -> tuple[bytes, bytes]:
    """``w2`` answered with the firmware's table showing ``pose`` as the WORLD row."""
    table = console_proto.format_w_table(pose, (0.0,) * 6, (0,) * 6)
    return (b"w2\r", b"w2\r\n" + "".join(f"{line}\r\n" for line in table).encode() + PROMPT)


class _ScriptedTransport(asyncio.Transport):
    """Checks what the driver writes against the script and feeds the recorded answers."""

    def __init__(self, reader: asyncio.StreamReader, script: Script) -> None:
        super().__init__()
        self.reader = reader
        self.script = list(script)
        self.used = 0
        self.mismatch: str | None = None
        self.closed = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        sent = bytes(data)
        if self.mismatch is not None:
            return
        if self.used >= len(self.script):
            self.mismatch = f"unexpected write {sent!r} after the script ended"
            return
        expected, answer = self.script[self.used]
        if sent != expected:
            self.mismatch = f"exchange {self.used}: sent {sent!r}, expected {expected!r}"
            return
        self.used += 1
        if answer:
            self.reader.feed_data(answer)

    def is_closing(self) -> bool:
        return self.closed

    def abort(self) -> None:
        self.closed = True

    def close(self) -> None:
        self.closed = True


class ScriptedRobot(C500CRobot):
    def __init__(self, script: Script, *, prepare: bool = True, **settings: Any) -> None:
        values = {"command_timeout_s": 0.5, **settings}
        super().__init__(RobotSettings(**values), port="scripted", prepare=prepare)
        self.script = script
        self.transport: _ScriptedTransport | None = None

    async def _open_port(self) -> Connection:
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        protocol = asyncio.StreamReaderProtocol(reader)
        self.transport = _ScriptedTransport(reader, self.script)
        writer = asyncio.StreamWriter(self.transport, protocol, reader, loop)
        return Connection(reader, writer, self.transcript, self.counters)

    def assert_all_used(self) -> None:
        assert self.transport is not None
        assert self.transport.mismatch is None, self.transport.mismatch
        assert self.transport.used == len(self.script), (
            f"only {self.transport.used} of {len(self.script)} exchanges used"
        )
