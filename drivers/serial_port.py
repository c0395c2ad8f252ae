"""Opening a serial port as asyncio streams, for both C500C links: the console
(drivers/c500c/link.py) and the fast path (drivers/c500c/server_link.py) had a copy each.

The port is opened in a worker thread (opening can block: USB adapters, termios; never on the
event loop), non-blocking (``timeout=0``) and without software flow control, then wrapped by
pyserial-asyncio into a reader and a writer. What a link builds on the streams stays its own.
"""

from __future__ import annotations

import asyncio
from typing import Any

import serial
import serial_asyncio

from drivers.errors import NotConnectedError


async def open_serial(
    device: str,
    port: str,
    *,
    baudrate: int,
    bytesize: int,
    parity: str,
    stopbits: float,
    rtscts: bool,
) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """``port`` (a device path or a pyserial URL such as ``socket://``) as a reader and a
    writer; a port that cannot be opened is a :class:`NotConnectedError` of ``device``."""

    def open_blocking() -> Any:
        # Opening a port can block (USB adapters, termios): never on the event loop.
        return serial.serial_for_url(
            port,
            baudrate=baudrate,
            bytesize=bytesize,
            parity=parity,
            stopbits=stopbits,
            rtscts=rtscts,
            xonxoff=False,
            timeout=0,
            # one owner per port (issue 26): a second process opening it (a check while the
            # daemon runs) gets one line instead of interleaving with the daemon's commands
            exclusive=True,
        )

    try:
        instance = await asyncio.to_thread(open_blocking)
    except (serial.SerialException, OSError, ValueError) as err:
        if "exclusively lock" in str(err):
            raise NotConnectedError(
                device, f"{port} is in use by another process (it is opened exclusively)"
            ) from err
        raise NotConnectedError(device, f"cannot open {port}: {err}") from err
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    protocol = asyncio.StreamReaderProtocol(reader)
    transport, _ = await serial_asyncio.connection_for_serial(loop, lambda: protocol, instance)
    return reader, asyncio.StreamWriter(transport, protocol, reader, loop)
