"""One open C500C console link: bytes out and in, counted and optionally transcribed.

The robot driver (drivers/c500c.py) frames replies on top of this; ``thermocomp robot check
--transcript FILE`` writes the :class:`Transcript`, and tests replay one (every byte the host
sends must be the recorded one, every recorded answer is fed back).

A transcript file is JSON lines, one per chunk in the order it crossed the line:
``{"t": seconds since the port opened, "dir": "host" | "console", "data": "..."}`` where
``data`` holds the exact bytes as a latin-1 string (JSON escapes CR, LF and Ctrl-E).
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

Direction = Literal["host", "console"]


class LinkLost(Exception):
    """The port closed or failed under us (internal; surfaces as NotConnectedError)."""


@dataclass(frozen=True, slots=True)
class TranscriptEntry:
    t_s: float
    direction: Direction
    data: bytes

    def as_json(self) -> str:
        return json.dumps(
            {"t": round(self.t_s, 6), "dir": self.direction, "data": self.data.decode("latin-1")}
        )


@dataclass
class Transcript:
    """Every byte exchanged with the console, in order."""

    entries: list[TranscriptEntry] = field(default_factory=list)
    started_s: float = field(default_factory=time.perf_counter)

    def record(self, direction: Direction, data: bytes) -> None:
        self.entries.append(TranscriptEntry(time.perf_counter() - self.started_s, direction, data))

    def sent(self) -> bytes:
        return b"".join(e.data for e in self.entries if e.direction == "host")

    def received(self) -> bytes:
        return b"".join(e.data for e in self.entries if e.direction == "console")

    def write(self, path: Path) -> None:
        path.write_text("".join(entry.as_json() + "\n" for entry in self.entries), "utf-8")

    @classmethod
    def read(cls, path: Path) -> Transcript:
        return cls.from_lines(path.read_text("utf-8").splitlines())

    @classmethod
    def from_lines(cls, lines: Iterable[str]) -> Transcript:
        entries = []
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                item = json.loads(line)
                direction = item["dir"]
                if direction not in ("host", "console"):
                    raise ValueError(f"dir must be host or console, not {direction!r}")
                entries.append(
                    TranscriptEntry(float(item["t"]), direction, item["data"].encode("latin-1"))
                )
            except (ValueError, KeyError, TypeError, UnicodeEncodeError) as err:
                raise ValueError(f"transcript line {number}: {err}") from err
        return cls(entries=entries)

    def exchanges(self) -> list[tuple[bytes, bytes]]:
        """The transcript as (what the host wrote, everything the console answered before the
        host's next write): the script of a replay."""
        script: list[tuple[bytes, bytes]] = []
        answer_before = b""
        for entry in self.entries:
            if entry.direction == "host":
                script.append((entry.data, b""))
            elif script:
                sent, answer = script[-1]
                script[-1] = (sent, answer + entry.data)
            else:
                answer_before += entry.data  # printed before the host said anything
        if answer_before and script:
            raise ValueError("the console spoke before the host's first write")
        return script


@dataclass
class ByteCounters:
    """Bytes moved over every connection of one driver."""

    sent: int = 0
    received: int = 0


class Connection:
    """An open port as a reader and a writer, and a pending buffer of what was read but not yet
    consumed (the next command's reply, when commands were written together)."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        transcript: Transcript | None = None,
        counters: ByteCounters | None = None,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.transcript = transcript
        self.counters = counters if counters is not None else ByteCounters()
        self.pending = bytearray()

    def write(self, data: bytes) -> None:
        """Hand ``data`` to the transport: synchronous, so no other task can write in between."""
        self.writer.write(data)
        self.counters.sent += len(data)
        if self.transcript is not None:
            self.transcript.record("host", data)

    async def read_more(self) -> bytes:
        """Wait for the next chunk and append it to ``pending`` (cancellation-safe: a cancelled
        read consumes nothing)."""
        try:
            chunk = await self.reader.read(4096)
        except OSError as err:
            raise LinkLost(str(err)) from err
        if not chunk:
            raise LinkLost("end of file")
        self.pending += chunk
        self.counters.received += len(chunk)
        if self.transcript is not None:
            self.transcript.record("console", chunk)
        return chunk

    def take(self, end: int) -> bytes:
        """Remove and return the first ``end`` pending bytes."""
        data = bytes(self.pending[:end])
        del self.pending[:end]
        return data

    def close(self) -> None:
        transport = self.writer.transport
        if not transport.is_closing():  # a lost port has already closed its transport
            transport.abort()
