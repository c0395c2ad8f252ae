"""The C500C emulator's side of the line: the master end of a pseudo-terminal or a TCP client
(:class:`Link`), and the pacing that makes every byte cost its bit times at the baud rate.
The emulator that serves the console over them is drivers/sim/emulator.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import pty
import tty
from typing import Protocol

#: Bits on the wire per character with 8N1 framing (start bit, 8 data bits, stop bit).
BITS_PER_CHARACTER = 10


class Link(Protocol):
    """One connection of the emulated console: a pty (:class:`PtyLink`) or a TCP client."""

    async def read(self) -> bytes: ...  # b"" at end of link

    async def write(self, data: bytes) -> None: ...

    def close(self) -> None: ...


def _set_once(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


class PtyLink:
    """The master side of a pseudo-terminal, non-blocking, driven by the event loop."""

    def __init__(self) -> None:
        self.master_fd, self.slave_fd = pty.openpty()
        # Raw mode: no echo or CR/LF translation by the line discipline; the console echoes.
        tty.setraw(self.slave_fd)
        os.set_blocking(self.master_fd, False)
        self.slave_path = os.ttyname(self.slave_fd)
        self.closed = False

    async def read(self) -> bytes:
        loop = asyncio.get_running_loop()
        while not self.closed:
            try:
                return os.read(self.master_fd, 4096)
            except BlockingIOError:
                pass
            except OSError as err:
                if err.errno == errno.EIO:
                    return b""
                raise
            ready: asyncio.Future[None] = loop.create_future()
            loop.add_reader(self.master_fd, _set_once, ready)
            try:
                await ready
            finally:
                loop.remove_reader(self.master_fd)
        return b""

    async def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self.closed:
            try:
                view = view[os.write(self.master_fd, view) :]
            except BlockingIOError:
                await asyncio.sleep(0.001)  # the pty buffer is full: the host is not reading

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            # The slave fd we hold keeps the pty alive between host reconnections; closing both
            # ends is what an unplugged cable looks like to the host (EIO on its reads).
            os.close(self.master_fd)
            os.close(self.slave_fd)


class StreamLink:
    """A TCP client of the emulated console (pyserial's ``socket://`` URL)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._reader, self._writer = reader, writer

    async def read(self) -> bytes:
        try:
            return await self._reader.read(4096)
        except ConnectionError:
            return b""

    async def write(self, data: bytes) -> None:
        if self._writer.is_closing():
            return
        self._writer.write(data)
        with contextlib.suppress(ConnectionError):
            await self._writer.drain()

    def close(self) -> None:
        self._writer.close()


class Pacer:
    """10 bit times per character at the baud rate (docs/reference/c500c-console.md: 0.17 ms per
    byte at 57600)."""

    def __init__(self, baudrate: int, enabled: bool) -> None:
        self.byte_s = BITS_PER_CHARACTER / baudrate
        self.enabled = enabled
        self._free_at = 0.0

    async def take(self, byte_count: int) -> None:
        """Wait until ``byte_count`` more bytes have crossed the line."""
        if not self.enabled or byte_count == 0:
            return
        loop = asyncio.get_running_loop()
        self._free_at = max(self._free_at, loop.time()) + byte_count * self.byte_s
        await asyncio.sleep(max(self._free_at - loop.time(), 0.0))


class LinkClosed(Exception):
    """A `close` fault ended the conversation (the link is closed already)."""
