"""An asyncio client of UR's Dashboard Server (TCP 29999): one command line, one answer line
(UR's Dashboard Server manual, e-Series). One connection per command: the Dashboard Server
serves several clients and each exchange is independent, so no connection state can be left
half-way by a cancelled caller.
"""

from __future__ import annotations

import asyncio
import contextlib

from drivers.errors import DeviceReportedError, DeviceTimeoutError, NotConnectedError

DEVICE = "robot"
#: The longest answer read (bytes).
MAX_ANSWER_BYTES = 4096


class DashboardClient:
    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self.host = host
        self.port = port
        self.timeout_s = timeout_s

    async def command(self, line: str) -> str:
        """Send ``line``, return the answer line (without its newline)."""
        if "\n" in line:
            raise ValueError("one command line without a newline")
        writer: asyncio.StreamWriter | None = None
        try:
            async with asyncio.timeout(self.timeout_s):
                reader, writer = await asyncio.open_connection(
                    self.host, self.port, limit=MAX_ANSWER_BYTES
                )
                await reader.readline()  # the welcome line
                writer.write(f"{line}\n".encode("ascii"))
                answer = await reader.readline()
        except TimeoutError as err:
            raise DeviceTimeoutError(DEVICE, f"Dashboard Server: no answer to {line!r}") from err
        except (OSError, ValueError) as err:
            raise NotConnectedError(
                DEVICE, f"Dashboard Server {self.host}:{self.port}: {err}"
            ) from err
        finally:
            if writer is not None:
                with contextlib.suppress(OSError):
                    writer.transport.abort()
        if not answer.endswith(b"\n"):
            raise NotConnectedError(DEVICE, f"Dashboard Server closed the connection ({line!r})")
        return answer.decode("ascii", "replace").rstrip("\r\n")

    async def _expect(self, line: str, expected: str) -> None:
        answer = await self.command(line)
        if not answer.startswith(expected):
            raise DeviceReportedError(DEVICE, None, f"Dashboard {line!r}: {answer}")

    async def play(self) -> None:
        await self._expect("play", "Starting program")

    async def pause(self) -> None:
        await self._expect("pause", "Pausing program")

    async def stop(self) -> None:
        await self._expect("stop", "Stopped")

    async def program_state(self) -> str:
        """``PLAYING``, ``PAUSED`` or ``STOPPED`` (the word before the program's name)."""
        return (await self.command("programState")).split(" ", 1)[0]

    async def robot_mode(self) -> str:
        return (await self.command("robotmode")).removeprefix("Robotmode: ")

    async def safety_status(self) -> str:
        return (await self.command("safetystatus")).removeprefix("Safetystatus: ")
