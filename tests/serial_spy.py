"""A spy on the robot links' serial writers (issue 26): every chunk handed to a port's writer,
with the time it was handed over, for both C500C links (the console's command lines and the
fast path's frames). A test asserts that no motion command was written after a hold's answer.

It wraps drivers/serial_port.py's ``open_serial`` where each link imported it, so it sees the
bytes at the last point before the transport, whatever driver code wrote them."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest

from drivers.c500c import link as console_link
from drivers.c500c import protocol as console_proto
from drivers.c500c import server_link
from drivers.c500c import server_protocol as server_proto

_SERVER_MOTION = {
    int(server_proto.RequestType.MOVE_GOAL),
    int(server_proto.RequestType.MOVE_RELATIVE),
}


@dataclass
class Written:
    at: float  # time.monotonic() when handed to the writer
    data: bytes
    link: str  # "console" or "server"


@dataclass
class SerialSpy:
    chunks: list[Written] = field(default_factory=list)

    def motions(self) -> list[tuple[float, str]]:
        """Every motion command written: (time, what)."""
        found: list[tuple[float, str]] = []
        for chunk in self.chunks:
            if chunk.link == "console":
                for line in chunk.data.decode("ascii", errors="replace").splitlines():
                    if line.strip() and console_proto.is_motion_command(line):
                        found.append((chunk.at, line.strip()))
            else:
                decoder = server_proto.FrameDecoder()
                for event in decoder.feed(chunk.data):
                    if isinstance(event, server_proto.Frame) and event.type in _SERVER_MOTION:
                        found.append((chunk.at, server_proto.RequestType(event.type).name))
        return found

    def motions_after(self, moment: float) -> list[tuple[float, str]]:
        return [(at, what) for at, what in self.motions() if at > moment]


class _SpyWriter:
    """A StreamWriter whose write() is logged, the rest delegated."""

    def __init__(self, writer: asyncio.StreamWriter, spy: SerialSpy, link: str) -> None:
        self._writer = writer
        self._spy = spy
        self._link = link

    def write(self, data: bytes) -> None:
        self._spy.chunks.append(Written(time.monotonic(), bytes(data), self._link))
        self._writer.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._writer, name)


def _wrap(opener: Callable[..., Any], spy: SerialSpy, link: str) -> Callable[..., Any]:
    async def open_spied(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
        reader, writer = await opener(*args, **kwargs)
        return reader, _SpyWriter(writer, spy, link)

    return open_spied


@contextmanager
def spy_serial(monkeypatch: pytest.MonkeyPatch) -> Iterator[SerialSpy]:
    spy = SerialSpy()
    console = _wrap(console_link.open_serial, spy, "console")
    monkeypatch.setattr(console_link, "open_serial", console)
    monkeypatch.setattr(server_link, "open_serial", _wrap(server_link.open_serial, spy, "server"))
    yield spy
